// stillpoint-synth: generates dynamic RGB-D sequences with ground-truth masks
// (movers composited into a real TUM sequence, or a fully synthetic room) and
// scores dynamic-feature flags against those masks.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/program.hpp"
#include "stillpoint/synth/config.hpp"
#include "stillpoint/synth/edit.hpp"
#include "stillpoint/synth/generator.hpp"
#include "stillpoint/synth/score.hpp"

namespace {

using namespace stillpoint;
using namespace stillpoint::synth;

#ifndef STILLPOINT_PHOTO_DIR
#define STILLPOINT_PHOTO_DIR ""
#endif

constexpr const char* kUsage =
    "usage: stillpoint-synth overlay INPUT_DIR OUTPUT_DIR --camera fr1|fr2|fr3|CAMERA.yaml\n"
    "                        (--config MOVERS.yaml | --preset NAME) [--render-poses TRAJ.txt] [common options]\n"
    "       stillpoint-synth room OUTPUT_DIR (--config ROOM.yaml | --preset NAME)\n"
    "                        [--motion static|xyz|rpy|halfsphere|loop] [--frames N] [--size WxH] [common options]\n"
    "       stillpoint-synth score SEQUENCE_DIR FEATURES.txt [--min-features N] [--min-speed M_S] [--per-frame]\n"
    "       stillpoint-synth edit INPUT_DIR OUTPUT_DIR [--cover START:SECONDS ...] [--cut START:SECONDS ...]\n"
    "                        [--there-and-back] [--camera fr1|fr2|fr3|CAMERA.yaml (its depth_factor)]\n"
    "       stillpoint-synth presets\n"
    "common options: [--seed N] [--blur] [--threads N] [--max-frames N] [--png-compression 0-9 (default 0: uncompressed, fastest)]\n"
    "                [--no-write] [--photo-dir DIR] [--cutout MASK.png] [--face-camera]\n"
    "\n"
    "overlay: renders the movers into every frame of a TUM sequence with groundtruth.txt at the\n"
    "  ground-truth camera pose (z-tested against the real depth) and writes a TUM-layout folder\n"
    "  with mask/ (16-bit, 0 = static, k = mover k), mask.txt and movers.yaml.\n"
    "  --render-poses TRAJ.txt places the movers by TRAJ.txt (TUM format, one map, e.g. a replay of\n"
    "  the input), rigidly aligned onto groundtruth.txt: motion capture is off the images by up to\n"
    "  a degree, so a mover placed by it drifts against the real scene even where it stands still.\n"
    "  Frames without a ground-truth pose are skipped as before; groundtruth.txt stays what the\n"
    "  output is scored against.\n"
    "room: renders a textured room with movers along a TUM-like camera motion.\n"
    "score: FEATURES.txt has one line per feature 'timestamp u v flagged(0/1)' (timestamps as in\n"
    "  rgb.txt, '#' comments); prints precision/recall of flagged features against the masks.\n"
    "  --min-speed M_S: movers slower than this in a frame (movers.txt) are still there: their\n"
    "  features count for no recall, and flags on them are no false positives.\n"
    "--cutout cuts every poster mover along MASK.png (kept where >= 128), e.g. a person cut out of\n"
    "  its photo: stillpoint-segment --card CARD --out DIR PHOTO writes DIR/<photo>_mask.png.\n"
    "--face-camera turns every poster mover to face the camera in each frame (a cut-out person\n"
    "  stays recognisable; a flat poster seen edge-on does not).\n"
    "edit: a copy of a TUM sequence in which the camera loses track of the world: --cover S:D\n"
    "  makes the frames from S s (after the first frame) for D s black with zero depth, while the\n"
    "  camera moves on; --cut S:D leaves those frames out and closes the gap in the stamps (the\n"
    "  camera jumps); --there-and-back plays the sequence forwards, then backwards (a revisit).\n"
    "  Kept images are hard-linked; groundtruth.txt follows every frame.\n"
    "--no-write renders without writing images (speed measurement). Exit status: 0 ok,\n"
    "1 bad input, 2 usage error. The last line of overlay/room output is machine-readable.\n";

struct Args {
  std::string command;
  std::vector<std::string> positional;
  std::string camera, config, preset, motion, photo_dir = STILLPOINT_PHOTO_DIR, size, cutout, render_poses;
  long seed = -1, threads = 2, max_frames = 0, frames = 0, png_compression = 0, min_features = 10;
  double min_speed = 0;
  bool blur = false, no_write = false, per_frame = false, face_camera = false, there_and_back = false;
  std::vector<TimeSpan> covers, cuts;
};


bool parseLong(const std::string& text, long lo, long hi, long* out) {
  char* end = nullptr;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end || v < lo || v > hi) return false;
  *out = v;
  return true;
}

bool parseDouble(const std::string& text, double lo, double hi, double* out) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end || !(v >= lo && v <= hi)) return false;
  *out = v;
  return true;
}

bool parseSpan(const std::string& text, TimeSpan* span) {
  const std::size_t colon = text.find(':');
  if (colon == std::string::npos) return false;
  return parseDouble(text.substr(0, colon), 0, 1e6, &span->start_s) &&
         parseDouble(text.substr(colon + 1), 1e-6, 1e6, &span->duration_s);
}

bool parseArgs(int argc, char** argv, Args* a, std::string* error) {
  if (argc < 2) {
    *error = "missing command";
    return false;
  }
  a->command = argv[1];
  for (int i = 2; i < argc; ++i) {
    const std::string s = argv[i];
    auto value = [&](std::string* out) {
      if (i + 1 >= argc) {
        *error = "option " + s + " needs a value";
        return false;
      }
      *out = argv[++i];
      return true;
    };
    auto number = [&](long lo, long hi, long* out) {
      std::string v;
      if (!value(&v)) return false;
      if (!parseLong(v, lo, hi, out)) {
        *error = s + " needs an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
        return false;
      }
      return true;
    };
    auto real = [&](double lo, double hi, double* out) {
      std::string v;
      if (!value(&v)) return false;
      if (!parseDouble(v, lo, hi, out)) {
        char range[64];
        std::snprintf(range, sizeof(range), " needs a number in [%g, %g]", lo, hi);
        *error = s + range;
        return false;
      }
      return true;
    };
    bool ok = true;
    if (s == "--camera") ok = value(&a->camera);
    else if (s == "--config") ok = value(&a->config);
    else if (s == "--preset") ok = value(&a->preset);
    else if (s == "--motion") ok = value(&a->motion);
    else if (s == "--photo-dir") ok = value(&a->photo_dir);
    else if (s == "--cutout") ok = value(&a->cutout);
    else if (s == "--render-poses") ok = value(&a->render_poses);
    else if (s == "--size") ok = value(&a->size);
    else if (s == "--seed") ok = number(0, 2147483647L, &a->seed);
    else if (s == "--threads") ok = number(1, 64, &a->threads);
    else if (s == "--max-frames") ok = number(1, 10000000, &a->max_frames);
    else if (s == "--frames") ok = number(1, 100000, &a->frames);
    else if (s == "--png-compression") ok = number(0, 9, &a->png_compression);
    else if (s == "--min-features") ok = number(1, 1000000, &a->min_features);
    else if (s == "--min-speed") ok = real(0, 100, &a->min_speed);
    else if (s == "--cover" || s == "--cut") {
      std::string v;
      TimeSpan span;
      ok = value(&v);
      if (ok && !parseSpan(v, &span)) {
        *error = s + " needs START:SECONDS (seconds after the first frame, duration > 0), got '" + v + "'";
        return false;
      }
      if (ok) (s == "--cover" ? a->covers : a->cuts).push_back(span);
    } else if (s == "--there-and-back") a->there_and_back = true;
    else if (s == "--blur") a->blur = true;
    else if (s == "--face-camera") a->face_camera = true;
    else if (s == "--no-write") a->no_write = true;
    else if (s == "--per-frame") a->per_frame = true;
    else if (!s.empty() && s[0] == '-') {
      *error = "unknown option " + s;
      return false;
    } else {
      a->positional.push_back(s);
    }
    if (!ok) return false;
  }
  return true;
}

std::string fmt(double v) {
  if (std::isnan(v)) return "nan";
  char b[32];
  std::snprintf(b, sizeof(b), "%.4f", v);
  return b;
}

int runScore(const Args& a) {
  Result<SequenceScoreReport> r =
      scoreSequence(a.positional[0], a.positional[1], static_cast<int>(a.min_features), a.min_speed);
  if (!r.ok()) {
    std::fprintf(stderr, "stillpoint-synth: %s\n", r.error().c_str());
    return 1;
  }
  if (a.per_frame) {
    std::printf("# timestamp features flagged on_movers true_pos precision recall eligible_movers eligible_recall\n");
    for (const auto& [stamp, f] : r->frames) {
      std::printf("%s %d %d %d %d %s %s %d %s\n", stamp.toSecondsString().c_str(), f.features, f.flagged,
                  f.on_movers, f.true_positives, fmt(f.precision()).c_str(), fmt(f.recall()).c_str(),
                  f.eligible_movers, fmt(f.eligibleRecall()).c_str());
    }
  }
  const SequenceScore& q = r->score;
  for (const auto& [id, m] : q.movers) {
    const auto it = q.mover_eligible_frames.find(id);
    std::printf("mover %u: features=%d flagged=%d recall=%s eligible_frames=%d\n", id, m.features, m.flagged,
                fmt(m.features ? double(m.flagged) / m.features : NAN).c_str(),
                it == q.mover_eligible_frames.end() ? 0 : it->second);
  }
  std::printf("frames scored %d (%d sequence frames without features), static frames with flags %d\n", q.frames,
              r->frames_without_features, q.static_frames_with_flags);
  std::printf("pooled: features=%ld flagged=%ld on_movers=%ld true_positives=%ld", q.features, q.flagged,
              q.on_movers, q.true_positives);
  if (a.min_speed > 0)
    std::printf(" on_still_movers=%ld flagged_on_still=%ld (min speed %.3f m/s)", q.on_still, q.still_flagged,
                a.min_speed);
  std::printf("\n");
  std::printf("precision_mean=%s recall_mean=%s eligible_precision_mean=%s eligible_recall_mean=%s "
              "eligible_frames=%d min_features=%ld\n",
              fmt(q.precision_mean).c_str(), fmt(q.recall_mean).c_str(), fmt(q.eligible_precision_mean).c_str(),
              fmt(q.eligible_recall_mean).c_str(), q.eligible_frames, a.min_features);
  return 0;
}

int runEdit(const Args& a) {
  EditOptions options;
  options.covers = a.covers;
  options.cuts = a.cuts;
  options.there_and_back = a.there_and_back;
  if (!a.camera.empty()) {
    Result<CameraModel> camera = loadCamera(a.camera);
    if (!camera.ok()) {
      std::fprintf(stderr, "stillpoint-synth: %s\n", camera.error().c_str());
      return 1;
    }
    options.depth_factor = camera->depth_factor;
  }
  auto summary = editSequence(a.positional[0], a.positional[1], options);
  if (!summary) {
    std::fprintf(stderr, "stillpoint-synth: %s\n", summary.error().c_str());
    return 1;
  }
  std::printf("frames=%zu covered=%zu cut=%zu ground_truth=%zu\n", summary->frames, summary->covered, summary->cut,
              summary->ground_truth);
  return 0;
}

Result<SynthConfig> configFrom(const Args& a) {
  if (a.config.empty() == a.preset.empty()) return Error{"give exactly one of --config and --preset"};
  Result<SynthConfig> c = a.config.empty() ? synthPreset(a.preset, a.photo_dir) : loadSynthConfig(a.config);
  if (!c.ok()) return c;
  if (a.seed >= 0) c->seed = static_cast<std::uint64_t>(a.seed);
  if (a.blur) c->blur.enabled = true;
  if (!a.cutout.empty()) {
    int posters = 0;
    for (MoverSpec& m : c->movers)
      if (m.shape == MoverShape::kPoster) m.cutout = std::filesystem::absolute(a.cutout).string(), ++posters;
    if (posters == 0) return Error{"--cutout: the configuration has no poster mover"};
  }
  if (a.face_camera) {
    int posters = 0;
    for (MoverSpec& m : c->movers)
      if (m.shape == MoverShape::kPoster) m.face_camera = true, ++posters;
    if (posters == 0) return Error{"--face-camera: the configuration has no poster mover"};
  }
  if (!a.motion.empty()) {
    Result<CameraMotion> m = parseCameraMotion(a.motion);
    if (!m.ok()) return Error{"--motion: " + m.error()};
    c->room.motion = *m;
  }
  if (a.frames > 0) c->room.frames = static_cast<int>(a.frames);
  if (!a.size.empty()) {
    int w = 0, h = 0;
    char x = 0;
    if (std::sscanf(a.size.c_str(), "%d%c%d", &w, &x, &h) != 3 || x != 'x') return Error{"--size needs WxH"};
    c->room.width = w;
    c->room.height = h;
  }
  if (Status s = c->validate(); !s) return Error{s.error()};
  return c;
}

void printReport(const GenerationReport& r, const std::string& out, bool wrote) {
  for (std::size_t k = 0; k < r.movers.size(); ++k) {
    std::printf("mover %zu '%s': visible in %d frames, coverage mean %.1f %% max %.1f %%\n", k + 1,
                r.movers[k].name.c_str(), r.movers[k].frames_visible, 100 * r.movers[k].mean_coverage,
                100 * r.movers[k].max_coverage);
  }
  const double n = std::max(1, r.frames);
  std::printf("frames %d (%d skipped: no camera pose), %d with movers, coverage mean %.1f %% max %.1f %%\n",
              r.frames, r.skipped_no_pose, r.frames_with_movers, 100 * r.coverage_mean, 100 * r.coverage_max);
  std::printf("per frame (thread time): load %.2f ms, render %.2f ms, write %.2f ms\n", r.load_ms / n,
              r.render_ms / n, r.write_ms / n);
  if (wrote) std::printf("output: %s\n", out.c_str());
  std::printf("frames=%d coverage_mean=%.4f coverage_max=%.4f wall_s=%.3f fps=%.1f\n", r.frames, r.coverage_mean,
              r.coverage_max, r.wall_s, r.wall_s > 0 ? r.frames / r.wall_s : 0.0);
}

}  // namespace

static int synthMain(int argc, char** argv) {
  Args a;
  std::string error;
  if (argc >= 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    std::fputs(kUsage, stdout);
    return 0;
  }
  if (!parseArgs(argc, argv, &a, &error)) {
    std::fprintf(stderr, "stillpoint-synth: %s\n%s", error.c_str(), kUsage);
    return 2;
  }
  const std::size_t want = a.command == "overlay" || a.command == "edit" ? 2
                           : a.command == "room"                       ? 1
                           : a.command == "score"                      ? 2
                                                                       : 0;
  if (a.command == "presets") {
    for (const std::string& n : presetNames()) std::printf("%s\n", n.c_str());
    return 0;
  }
  if (want == 0) {
    std::fprintf(stderr, "stillpoint-synth: unknown command '%s'\n%s", a.command.c_str(), kUsage);
    return 2;
  }
  if (a.positional.size() != want) {
    std::fprintf(stderr, "stillpoint-synth: %s needs %zu folder/file arguments\n%s", a.command.c_str(), want, kUsage);
    return 2;
  }
  if (!a.render_poses.empty() && a.command != "overlay") {
    std::fprintf(stderr, "stillpoint-synth: --render-poses is for overlay only\n%s", kUsage);
    return 2;
  }
  if (a.command == "score") return runScore(a);
  if (a.command == "edit") return runEdit(a);
  if (a.command == "overlay" && a.camera.empty()) {
    std::fprintf(stderr, "stillpoint-synth: overlay needs --camera\n%s", kUsage);
    return 2;
  }
  Result<SynthConfig> config = configFrom(a);
  if (!config.ok()) {
    std::fprintf(stderr, "stillpoint-synth: %s\n", config.error().c_str());
    return 1;
  }
  GenerateOptions opt;
  opt.threads = static_cast<int>(a.threads);
  opt.max_frames = static_cast<int>(a.max_frames);
  opt.png_compression = static_cast<int>(a.png_compression);
  opt.write_images = !a.no_write;
  opt.render_poses = a.render_poses;
  Result<GenerationReport> report = Error{""};
  std::string out;
  if (a.command == "overlay") {
    Result<CameraModel> camera = loadCamera(a.camera);
    if (!camera.ok()) {
      std::fprintf(stderr, "stillpoint-synth: %s\n", camera.error().c_str());
      return 1;
    }
    out = a.positional[1];
    report = generateOverlay(a.positional[0], out, *camera, *config, opt);
  } else {
    out = a.positional[0];
    report = generateRoom(out, *config, opt);
  }
  if (!report.ok()) {
    std::fprintf(stderr, "stillpoint-synth: %s\n", report.error().c_str());
    return 1;
  }
  printReport(*report, out, opt.write_images);
  return 0;
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-synth", synthMain, argc, argv); }
