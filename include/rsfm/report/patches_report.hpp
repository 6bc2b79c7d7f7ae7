#pragma once
// Output of `rsfm experiment patches` (docs/outputs.md, docs/patches.md):
//   patches.csv       exactly: scene,measurement,noise,rms_t,rms_q,normal_err_deg,beta_err_pct,frames_to_converge
//   patches.md        the same as a readable table with the extra columns, failures and options
//   patches_data.csv  per row and frame: the trial-mean normal error and beta error
//   patches.png/.svg  normal error against frame (scripts/plot_patches.py)
#include <filesystem>

#include "rsfm/report/report.hpp"
#include <string>

#include "rsfm/experiment/patches.hpp"

namespace rsfm::report {

std::string patchesCsv(const PatchesResult& r);
std::string patchesMarkdown(const PatchesResult& r, const std::string& command_line);
std::string patchesFigureData(const PatchesResult& r);
Figures writePatchesReport(const PatchesResult& r, const std::filesystem::path& dir, const std::string& command_line);

}  // namespace rsfm::report
