#pragma once
// A person model as a second opinion beside an instance model.
//
// An instance detector (COCO's YOLO) needs a person's outline to score it: a
// person close to the camera, cut by the image border or half hidden behind
// an object, falls under its score threshold, while a person-only model
// trained on near, cropped people (MediaPipe's selfie segmentation) paints
// them at once. That model also paints person-like objects (the TUM teddy
// bear, every frame), which the instance model names correctly. Together:
// the person model's pixels that no instance of the main model explains join
// the main segmentation as person instances.
#include <memory>

#include "stillpoint/core/result.hpp"
#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::semantic {

struct SecondOpinionOptions {
  // What is left of a person-model region outside the main model's instances
  // (every instance it keeps or names static; movable ones its post-filter
  // dropped do not count), opened by this many pixels (thin rims along an
  // explained object's outline are not a person)...
  int open_px = 6;
  // ...joins as a person when it covers at least this share of the image: a
  // person near enough to escape the detector fills a good part of the view;
  // far people are the detector's.
  double min_region_fraction = 0.03;
  // Only person-model regions whose mean probability is at least this count.
  double min_probability = 0.8;

  Status validate() const;
};

// The main card's "person" class id, which a person model's regions join as.
// Errors: the main card has no "person" class, or the person card decodes no
// person probability map.
Result<int> secondOpinionPersonId(const ModelCard& main, const ModelCard& person);

// Adds to `seg` (the main model's result) the regions of `people` (the person
// model's result on the same image) that no instance of `seg` explains, as
// instances of class `person_id` with Instance::second_opinion set. Returns
// how many it added; none when the two differ in size.
int joinPersonSecondOpinion(const Segmentation& people, int person_id, const SecondOpinionOptions& options,
                            Segmentation* seg);

// The main segmenter's card, classes and movable ids; its results gain the
// person model's unexplained regions as instances of the main card's
// "person" class (Instance::second_opinion). Errors: secondOpinionPersonId's,
// bad options. Threading as Segmenter: one caller at a time.
Result<std::unique_ptr<Segmenter>> withPersonSecondOpinion(std::unique_ptr<Segmenter> main,
                                                           std::unique_ptr<Segmenter> person,
                                                           const SecondOpinionOptions& options = {});

}  // namespace stillpoint::semantic
