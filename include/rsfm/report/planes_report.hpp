#pragma once
// Output of `rsfm experiment planes` (docs/outputs.md):
//   planes.csv      exactly: method,noise_px,rms_t,rms_q,normal_err_deg,face_angle_err_deg,beta_err_pct,ratio_to_batch
//   planes.md       the same as a readable table, the Cramer-Rao bounds, options, failures
//   planes_data.csv per method, noise level and frame: normal error and translation error
//   planes.png/.svg error against frame for each method (scripts/plot_planes.py)
#include <filesystem>

#include "rsfm/report/report.hpp"
#include <string>

#include "rsfm/experiment/planes.hpp"

namespace rsfm::report {

std::string planesCsv(const PlanesResult& r);
std::string planesMarkdown(const PlanesResult& r, const std::string& command_line);
std::string planesFigureData(const PlanesResult& r);
Figures writePlanesReport(const PlanesResult& r, const std::filesystem::path& dir, const std::string& command_line);

}  // namespace rsfm::report
