#include "stillpoint/semantic/person_second_opinion.hpp"

#include <opencv2/imgproc.hpp>

#include <exception>
#include <string>
#include <utility>
#include <vector>

namespace stillpoint::semantic {

Status SecondOpinionOptions::validate() const {
  if (open_px < 0 || open_px > 50) return Error{"person second opinion: 'open_px' must be in 0..50"};
  if (!(min_region_fraction > 0 && min_region_fraction < 1))
    return Error{"person second opinion: 'min_region_fraction' must be in (0, 1)"};
  if (!(min_probability >= 0 && min_probability <= 1))
    return Error{"person second opinion: 'min_probability' must be in [0, 1]"};
  return Status::success();
}

Result<int> secondOpinionPersonId(const ModelCard& main, const ModelCard& person) {
  const int person_id = main.classId("person");
  if (person_id < 0) return Error{"person second opinion: model '" + main.name + "' has no class 'person'"};
  if (person.decoder.type != DecoderType::kPersonProbability)
    return Error{"person second opinion: model '" + person.name +
                 "' is not a person model (its decoder is not person_probability)"};
  return person_id;
}

int joinPersonSecondOpinion(const Segmentation& people, int person_id, const SecondOpinionOptions& options,
                            Segmentation* seg) {
  const cv::Size size = seg->movable_mask.size();
  if (people.movable_mask.size() != size || seg->movable_mask.empty()) return 0;
  // What the main model has named: its static objects and the movers it keeps.
  cv::Mat explained(size, CV_8U, cv::Scalar(0));
  cv::Mat kept_people(size, CV_8U, cv::Scalar(0));
  for (const Instance& inst : seg->instances) {
    if (inst.area <= 0 || inst.mask.empty() || (inst.movable && !inst.kept)) continue;
    explained(inst.box).setTo(255, inst.mask);
    if (inst.movable && inst.class_id == person_id) kept_people(inst.box).setTo(255, inst.mask);
  }
  const double min_area = options.min_region_fraction * double(size.area());
  const cv::Mat kernel =
      cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * options.open_px + 1, 2 * options.open_px + 1));
  // The opening parts a piece from what explains its neighbours by up to
  // open_px; a piece within that reach of a kept person continues that person.
  const int reach = options.open_px + 2;
  cv::dilate(kept_people, kept_people,
             cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * reach + 1, 2 * reach + 1)));
  std::vector<Instance> added;
  for (const Instance& region : people.instances) {
    if (!region.movable || !region.kept || region.area < min_area || region.score < options.min_probability ||
        region.mask.empty())
      continue;
    cv::Mat left(size, CV_8U, cv::Scalar(0));
    left(region.box).setTo(255, region.mask);
    left.setTo(0, explained);
    if (options.open_px > 0) cv::morphologyEx(left, left, cv::MORPH_OPEN, kernel);
    cv::Mat labels, stats, centroids;
    const int n = cv::connectedComponentsWithStats(left, labels, stats, centroids, 8, CV_32S);
    for (int c = 1; c < n; ++c) {
      const int area = stats.at<int>(c, cv::CC_STAT_AREA);
      if (area < min_area) continue;
      const cv::Rect box(stats.at<int>(c, cv::CC_STAT_LEFT), stats.at<int>(c, cv::CC_STAT_TOP),
                         stats.at<int>(c, cv::CC_STAT_WIDTH), stats.at<int>(c, cv::CC_STAT_HEIGHT));
      cv::Mat piece;
      cv::compare(labels(box), c, piece, cv::CMP_EQ);
      // A piece that continues a person the main model keeps is that person's,
      // and the main model's outline is the one to trust: what the person model
      // adds there is what stands with the person (the box under the TUM bear).
      if (cv::countNonZero(kept_people(box) & piece) > 0) continue;
      Instance inst;
      inst.class_id = person_id;
      inst.class_name = "person";
      inst.score = region.score;
      inst.box = box;
      inst.mask = piece;
      inst.area = area;
      inst.movable = true;
      inst.second_opinion = true;
      added.push_back(std::move(inst));
    }
  }
  for (Instance& inst : added) {
    seg->movable_mask(inst.box).setTo(255, inst.mask);
    if (!seg->labels.empty() && seg->labels.size() == size) seg->labels(inst.box).setTo(person_id, inst.mask);
    seg->instances.push_back(std::move(inst));
  }
  if (!added.empty()) seg->movable_pixels = cv::countNonZero(seg->movable_mask);
  return static_cast<int>(added.size());
}

namespace {

class SecondOpinionSegmenter final : public Segmenter {
 public:
  SecondOpinionSegmenter(std::unique_ptr<Segmenter> main, std::unique_ptr<Segmenter> person,
                         const SecondOpinionOptions& options, int person_id)
      : main_(std::move(main)), person_(std::move(person)), options_(options), person_id_(person_id) {}

  Result<Segmentation> segment(const cv::Mat& bgr) override {
    auto seg = main_->segment(bgr);
    if (!seg) return seg;
    auto people = person_->segment(bgr);
    if (!people) return Error{"person model '" + person_->card().name + "': " + people.error()};
    try {
      joinPersonSecondOpinion(*people, person_id_, options_, &*seg);
    } catch (const std::exception& e) {
      return Error{"person model '" + person_->card().name + "': cannot join its regions: " + e.what()};
    }
    seg->timing.preprocess_ms += people->timing.preprocess_ms;
    seg->timing.inference_ms += people->timing.inference_ms;
    seg->timing.decode_ms += people->timing.decode_ms;
    seg->timing.total_ms += people->timing.total_ms;
    return seg;
  }

  const ModelCard& card() const override { return main_->card(); }
  const std::vector<int>& movableClassIds() const override { return main_->movableClassIds(); }

 private:
  std::unique_ptr<Segmenter> main_, person_;
  SecondOpinionOptions options_;
  int person_id_;
};

}  // namespace

Result<std::unique_ptr<Segmenter>> withPersonSecondOpinion(std::unique_ptr<Segmenter> main,
                                                           std::unique_ptr<Segmenter> person,
                                                           const SecondOpinionOptions& options) {
  if (!main || !person) return Error{"person second opinion: both segmenters are needed"};
  if (Status s = options.validate(); !s) return Error{s.error()};
  auto person_id = secondOpinionPersonId(main->card(), person->card());
  if (!person_id) return Error{person_id.error()};
  return std::unique_ptr<Segmenter>(
      std::make_unique<SecondOpinionSegmenter>(std::move(main), std::move(person), options, *person_id));
}

}  // namespace stillpoint::semantic
