// A deterministic mutation fuzzer for every parser of files a user or an
// attacker controls: camera YAML, SLAM options, the daemon config, the ipc
// config, model cards, TUM list files, trajectories, map files, vocabularies, and the shared-memory
// pose ring as its C reader maps it. Each target starts
// from real seed files (the shipped configs, the bundled excerpt's lists)
// and runs a fixed number of mutations from a fixed seed, so a failure is
// reproducible by its case number. A case passes when the parser returns
// (a value or an error) without throwing; a crash or a sanitizer report
// fails the process, and so the test.
//
// usage: stillpoint-fuzz [--cases N] [--seed S] [--target NAME] [--keep DIR]
//   N mutated inputs per target (default 2000); --keep writes every failing input to DIR.
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include "config.hpp"
#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint_shm.h"
#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/checksum.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/features/vocabulary.hpp"
#include "stillpoint/ipc/options.hpp"
#include "stillpoint/semantic/model_card.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/system.hpp"

namespace fs = std::filesystem;
using namespace stillpoint;

namespace {

std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void writeFile(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

// Tokens that parsers meet at their edges.
const std::vector<std::string> kInteresting = {
    "0", "-1", "1e300", "-1e300", "nan", ".nan", "inf", "-.inf", "9999999999.0", "9223372036.854775807",
    "2147483648", "-2147483649", "1e-320", "", "~", "null", "[]", "{}", "[a, b]", "{a: 1}", "? [a, b]\n: 1",
    "&a x", "*a", "!!binary AAAA", "\"\\u0000\"", "'", "\"", "#", ":", "- ", "\t", "\r\n", "\xff\xfe", "true",
    "yes", "0x10", "1_000", "+.5", "1.", ".", "..", "/dev/zero", "/nonexistent/x", "../../etc/passwd"};

// One mutation of `text`, chosen by `rng`.
std::string mutate(const std::string& text, std::mt19937& rng) {
  std::string s = text;
  const auto pick = [&](std::size_t n) { return n == 0 ? std::size_t{0} : std::size_t(rng() % n); };
  const int rounds = 1 + static_cast<int>(rng() % 4);
  for (int r = 0; r < rounds; ++r) {
    switch (rng() % 10) {
      case 0:  // flip a byte
        if (!s.empty()) s[pick(s.size())] ^= static_cast<char>(1 << (rng() % 8));
        break;
      case 1:  // delete a span
        if (!s.empty()) {
          const std::size_t at = pick(s.size());
          s.erase(at, 1 + pick(std::min<std::size_t>(32, s.size() - at)));
        }
        break;
      case 2:  // insert an interesting token
        s.insert(pick(s.size() + 1), kInteresting[pick(kInteresting.size())]);
        break;
      case 3: {  // replace a number-like run or value after a colon with a token
        const std::size_t colon = s.find(':', pick(s.size() + 1));
        if (colon != std::string::npos) {
          const std::size_t end = s.find('\n', colon);
          s.replace(colon + 1, (end == std::string::npos ? s.size() : end) - colon - 1,
                    " " + kInteresting[pick(kInteresting.size())]);
        }
        break;
      }
      case 4: {  // duplicate a line
        std::vector<std::string> lines;
        std::istringstream in(s);
        for (std::string l; std::getline(in, l);) lines.push_back(l);
        if (lines.empty()) break;
        const std::size_t k = pick(lines.size());
        lines.insert(lines.begin() + static_cast<std::ptrdiff_t>(pick(lines.size() + 1)), lines[k]);
        s.clear();
        for (const auto& l : lines) s += l + "\n";
        break;
      }
      case 5:  // truncate
        s.resize(pick(s.size() + 1));
        break;
      case 6: {  // deep nesting
        const int depth = 1 + static_cast<int>(rng() % 800);
        s.insert(pick(s.size() + 1), std::string(depth, '[') + std::string(depth, ']'));
        break;
      }
      case 7: {  // change indentation of a line
        const std::size_t nl = s.find('\n', pick(s.size() + 1));
        if (nl != std::string::npos) s.insert(nl + 1, std::string(1 + rng() % 6, ' '));
        break;
      }
      case 8: {  // splice a random chunk of the text elsewhere
        if (s.size() < 2) break;
        const std::size_t at = pick(s.size()), len = 1 + pick(std::min<std::size_t>(64, s.size() - at));
        const std::string chunk = s.substr(at, len);
        s.insert(pick(s.size() + 1), chunk);
        break;
      }
      default:  // a random byte
        s.insert(pick(s.size() + 1), 1, static_cast<char>(rng() % 256));
    }
  }
  return s;
}

struct Target {
  std::string name;
  std::vector<std::string> seeds;
  // Parses the file at `path`; true when it returned (ok or an error).
  std::function<void(const fs::path& dir, const std::string& text)> parse;
};

}  // namespace

int main(int argc, char** argv) {
  int cases = 2000;
  unsigned seed = 1;
  std::string only, keep;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--cases" && i + 1 < argc) cases = std::atoi(argv[++i]);
    else if (a == "--seed" && i + 1 < argc) seed = static_cast<unsigned>(std::atoi(argv[++i]));
    else if (a == "--target" && i + 1 < argc) only = argv[++i];
    else if (a == "--keep" && i + 1 < argc) keep = argv[++i];
    else {
      std::cerr << "usage: stillpoint-fuzz [--cases N] [--seed S] [--target NAME] [--keep DIR]\n";
      return 2;
    }
  }
  log::setLevel(log::Level::kError);  // loaders log what they read; the cases are thousands
  const fs::path source = STILLPOINT_SOURCE_DIR, data = STILLPOINT_DATA_DIR;
  const fs::path work = fs::temp_directory_path() / ("stillpoint_fuzz_" + std::to_string(::getpid()));
  fs::create_directories(work);
  const fs::path teddy = data / "tum_fr3_teddy_200";
  const auto seedsOf = [](std::initializer_list<fs::path> paths) {
    std::vector<std::string> out;
    for (const auto& p : paths)
      if (fs::exists(p)) out.push_back(readFile(p));
    return out;
  };

  std::vector<Target> targets;
  targets.push_back({"camera", seedsOf({source / "config/camera_example.yaml"}),
                     [](const fs::path& dir, const std::string& text) {
                       writeFile(dir / "camera.yaml", text);
                       (void)loadCameraYaml((dir / "camera.yaml").string());
                     }});
  targets.push_back({"slam-options", seedsOf({source / "config/slam.yaml"}),
                     [](const fs::path& dir, const std::string& text) {
                       writeFile(dir / "slam.yaml", text);
                       (void)slam::loadSlamOptions((dir / "slam.yaml").string());
                     }});
  targets.push_back({"daemon-config", seedsOf({source / "config/stillpointd.yaml"}),
                     [](const fs::path& dir, const std::string& text) {
                       writeFile(dir / "stillpointd.yaml", text);
                       (void)daemon::loadDaemonConfig((dir / "stillpointd.yaml").string());
                     }});
  targets.push_back({"ipc-config", seedsOf({source / "config/ipc.yaml"}),
                     [](const fs::path& dir, const std::string& text) {
                       writeFile(dir / "ipc.yaml", text);
                       (void)ipc::loadIpcOptions((dir / "ipc.yaml").string());
                     }});
  targets.push_back({"model-card", seedsOf({source / "models/person_selfie_256.yaml", source / "models/coco_yolov5s_seg_320.yaml"}),
                     [](const fs::path& dir, const std::string& text) {
                       writeFile(dir / "card.yaml", text);
                       (void)semantic::loadModelCard(dir / "card.yaml");
                     }});
  targets.push_back({"tum-lists", seedsOf({teddy / "rgb.txt"}),
                     [&teddy](const fs::path& dir, const std::string& text) {
                       // The mutated list as rgb.txt, the real depth list, images from the excerpt.
                       fs::create_directories(dir / "tum");
                       writeFile(dir / "tum" / "rgb.txt", text);
                       if (!fs::exists(dir / "tum" / "depth.txt")) fs::copy_file(teddy / "depth.txt", dir / "tum" / "depth.txt");
                       for (const char* sub : {"rgb", "depth"})
                         if (!fs::exists(dir / "tum" / sub)) fs::create_directory_symlink(teddy / sub, dir / "tum" / sub);
                       auto opened = dataset::TumDataset::open((dir / "tum").string());
                       if (opened && opened->size() > 0) (void)opened->load(0);
                     }});
  targets.push_back({"trajectory", seedsOf({teddy / "groundtruth.txt"}),
                     [](const fs::path& dir, const std::string& text) {
                       // The first 60 poses keep cases fast.
                       std::istringstream in(text);
                       std::string head, line;
                       for (int k = 0; k < 60 && std::getline(in, line); ++k) head += line + "\n";
                       writeFile(dir / "traj.txt", head);
                       (void)eval::readTumTrajectory((dir / "traj.txt").string());
                     }});

  // Map files: a real one, from the first frames of the excerpt. Half of the
  // cases get the header's size and checksum fixed up to match the mutated
  // payload, so that mutations reach the parser behind the checksum.
  std::string map_seed;
  if (fs::exists(teddy / "rgb.txt")) {
    auto data = dataset::TumDataset::open(teddy.string());
    slam::SlamOptions options;
    options.sequential = true;
    options.geometry.enabled = false;
    auto system = slam::SlamSystem::create(*cameraPreset("fr3"), options);
    if (data && system) {
      for (std::size_t i = 0; i < std::min<std::size_t>(12, data->size()); ++i)
        if (auto f = data->load(i)) (void)(*system)->track({f->stamp, f->gray, f->depth_m, f->bgr});
      (*system)->finish();
      if ((*system)->saveMap((work / "seed.map").string())) map_seed = readFile(work / "seed.map");
    }
  }
  int map_case = 0;
  targets.push_back({"map-file", map_seed.empty() ? std::vector<std::string>{} : std::vector<std::string>{map_seed},
                     [&map_case](const fs::path& dir, const std::string& bytes) {
                       std::string file = bytes;
                       if (++map_case % 2 == 0 && file.size() >= 40) {
                         const std::uint64_t size = file.size() - 40;
                         std::uint64_t h = 1469598103934665603ull;
                         for (std::size_t i = 40; i < file.size(); ++i) {
                           h ^= static_cast<unsigned char>(file[i]);
                           h *= 1099511628211ull;
                         }
                         std::memcpy(&file[16], &size, 8);
                         std::memcpy(&file[24], &h, 8);
                       }
                       writeFile(dir / "fuzz.map", file);
                       slam::SlamOptions options;
                       options.geometry.enabled = false;
                       auto system = slam::SlamSystem::create(*cameraPreset("fr3"), options);
                       if (system) (void)(*system)->loadMap((dir / "fuzz.map").string());
                     }});

  // Vocabulary files: a small real one (trained on random descriptors). Half
  // of the cases get the checksum fixed up, so mutations reach the tree checks.
  std::string vocab_seed;
  {
    std::mt19937 rng(5);
    std::vector<cv::Mat> images;
    for (int k = 0; k < 4; ++k) {
      cv::Mat d(60, 32, CV_8UC1);
      for (int r = 0; r < d.rows; ++r)
        for (int c = 0; c < d.cols; ++c) d.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(rng() & 0xff);
      images.push_back(d);
    }
    auto vocab = features::Vocabulary::train(images, {.branching = 4, .depth = 3});
    if (vocab && vocab->save((work / "seed.vocab").string())) vocab_seed = readFile(work / "seed.vocab");
  }
  int vocab_case = 0;
  targets.push_back({"vocabulary-file", vocab_seed.empty() ? std::vector<std::string>{} : std::vector<std::string>{vocab_seed},
                     [&vocab_case](const fs::path& dir, const std::string& bytes) {
                       std::string file = bytes;
                       if (++vocab_case % 2 == 0 && file.size() >= 8) {
                         const std::uint64_t h = fnv1a64(file.data(), file.size() - 8);
                         std::memcpy(&file[file.size() - 8], &h, 8);
                       }
                       writeFile(dir / "fuzz.vocab", file);
                       auto vocab = features::Vocabulary::load((dir / "fuzz.vocab").string());
                       if (vocab) {
                         // A loaded vocabulary must answer lookups within its words.
                         cv::Mat probe(3, 32, CV_8UC1, cv::Scalar(0x5a));
                         std::vector<features::WordId> words;
                         (void)vocab->transform(probe, &words);
                         for (features::WordId w : words)
                           if (w >= vocab->info().words) throw std::runtime_error("word out of range");
                       }
                     }});

  // The ring: a real one from the writer (a few records, capacity 8) as the
  // seed; each mutation replaces the file under the reader's name, which is
  // then opened and read to its end. The reader must refuse or read, never
  // fault on what another process left in /dev/shm.
  const std::string ring = "sp_fuzz_ring_" + std::to_string(::getpid());
  std::string ring_seed;
  {
    auto writer = ipc::ShmPoseWriter::create(ring, 8);
    if (writer) {
      sp_pose_record rec{};
      for (int k = 0; k < 11; ++k) {
        rec.sensor_stamp_ns = 1'000'000'000LL * k;
        rec.orientation[3] = 1;
        (*writer)->write(rec);
      }
      ring_seed = readFile((*writer)->path());
    }
  }
  (void)ipc::ShmPoseWriter::remove(ring);
  (void)ipc::ShmPoseWriter::remove(ring + "_objects");
  targets.push_back({"shm-ring", ring_seed.empty() ? std::vector<std::string>{} : std::vector<std::string>{ring_seed},
                     [&ring](const fs::path&, const std::string& bytes) {
                       const fs::path path = fs::path("/dev/shm") / ring;
                       writeFile(path, bytes);
                       sp_shm_reader r;
                       sp_shm_reader_init(&r);
                       if (sp_shm_reader_open(&r, ring.c_str(), SP_SHM_START_OLDEST) == SP_SHM_OK) {
                         sp_pose_record pose;
                         for (int k = 0; k < 64 && sp_shm_reader_next(&r, &pose) == SP_SHM_OK; ++k) {
                         }
                         (void)sp_shm_reader_latest(&r, &pose);
                       }
                       sp_shm_reader_close(&r);
                       fs::remove(path);
                     }});

  int failures = 0, ran_targets = 0;
  for (const Target& t : targets) {
    if (!only.empty() && t.name != only) continue;
    if (t.seeds.empty()) {
      std::cout << t.name << ": no seed file found, skipped\n";
      continue;
    }
    ++ran_targets;
    std::mt19937 rng(seed);
    const fs::path dir = work / t.name;
    fs::create_directories(dir);
    int errors_thrown = 0;
    for (int k = 0; k < cases; ++k) {
      const std::string input = mutate(t.seeds[static_cast<std::size_t>(k) % t.seeds.size()], rng);
      try {
        t.parse(dir, input);
      } catch (const std::exception& e) {
        ++errors_thrown;
        std::cout << t.name << ": case " << k << " threw: " << e.what() << "\n";
        if (!keep.empty()) {
          fs::create_directories(keep);
          writeFile(fs::path(keep) / (t.name + "_" + std::to_string(k)), input);
        }
      }
    }
    std::cout << t.name << ": " << cases << " cases, " << errors_thrown << " threw\n";
    failures += errors_thrown;
  }
  fs::remove_all(work);
  (void)ipc::ShmPoseWriter::remove(ring);
  (void)ipc::ShmPoseWriter::remove(ring + "_objects");
  if (ran_targets == 0) return 2;
  return failures == 0 ? 0 : 1;
}
