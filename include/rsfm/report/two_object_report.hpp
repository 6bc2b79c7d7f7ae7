#pragma once
// Output of `rsfm experiment two-object` (docs/outputs.md):
//   two_object.csv      exactly: noise_px,object,rot_err_deg,t_err_pct,normal_err_deg,beta_err_pct,failed
//   two_object.md       the same as a readable table, the objects' motions, failures, options
//   two_object_data.csv per noise level and frame: the errors of both objects and beta
//   two_object.png/.svg errors against frame (scripts/plot_two_object.py)
#include <filesystem>

#include "rsfm/report/report.hpp"
#include <string>

#include "rsfm/experiment/two_object.hpp"

namespace rsfm::report {

std::string twoObjectCsv(const TwoObjectResult& r);
std::string twoObjectMarkdown(const TwoObjectResult& r, const std::string& command_line);
std::string twoObjectFigureData(const TwoObjectResult& r);
Figures writeTwoObjectReport(const TwoObjectResult& r, const std::filesystem::path& dir, const std::string& command_line);

}  // namespace rsfm::report
