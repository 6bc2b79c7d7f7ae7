#pragma once
// The regime suite: a versioned list of named rendered sequences, each a set of render options
// with a fixed seed (bench/regimes.json; docs/regimes.md). The copy in the repository is built into
// the binary, so `rsfm render regime NAME` and `rsfm bench regimes` work from anywhere; `--suite
// FILE` reads another.
//
// File format (JSON):
//   {"format": "rsfm-regimes", "version": 1,
//    "sequences": [{"name": "box-orbit", "why": "one line", "axes": ["scene:box", ...],
//                   "options": {"scene": "box", "frames": 150, "seed": 1, ...}}, ...]}
// `options` takes the keys of render::optionsToJson (every key optional but "seed"; absent keys
// keep RenderOptions' defaults; unknown keys are errors). Names are unique, [a-z0-9-]+.
#include <string>
#include <vector>

#include "rsfm/render/scene_render.hpp"

namespace rsfm::render {

struct Regime {
  std::string name;
  std::string why;                ///< what the sequence is for
  std::vector<std::string> axes;  ///< the axes it covers ("scene:corner", "motion:still-start", ...)
  RenderOptions options;
  std::string options_json;       ///< options as given (canonical: optionsToJson of `options`)
};

struct RegimeSuite {
  int version = 1;
  std::string source;  ///< file name, or "built-in"
  std::vector<Regime> sequences;
  /// nullptr when absent.
  const Regime* find(const std::string& name) const;
  /// "a, b, c".
  std::string names() const;
};

/// Parses a suite; throws io::InputError "SOURCE: problem" (with the sequence's name) on any
/// malformed entry, unknown option, invalid option value (render::validate) or duplicate name.
RegimeSuite parseRegimeSuite(const std::string& text, const std::string& source);
/// Reads a suite file (io::InputError when unreadable or malformed).
RegimeSuite readRegimeSuite(const std::string& path);
/// The suite built into the binary (bench/regimes.json at build time).
const RegimeSuite& builtinRegimeSuite();
/// The built-in suite's text.
const std::string& builtinRegimeSuiteText();

/// Render options from a JSON object of optionsToJson's keys over the defaults. Throws
/// std::invalid_argument naming the key on an unknown key or a wrong type (not validate()).
RenderOptions optionsFromJson(const std::string& json_object);

}  // namespace rsfm::render
