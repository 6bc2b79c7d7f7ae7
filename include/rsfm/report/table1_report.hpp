#pragma once
// Output of `rsfm experiment table1` (format documented in docs/outputs.md):
//   table1.csv    exactly: formulation,noise_px,m_t,sigma_t,m_q,sigma_q,r_s,r_c
//   table1.md     the same next to the paper's numbers, plus every option and extra statistics
//   fig1_data.csv trial-averaged estimates per frame (input of the figure)
//   fig1.png/.svg the figure (matplotlib, scripts/plot_table1.py)
#include <filesystem>

#include "rsfm/report/report.hpp"
#include <string>

#include "rsfm/experiment/table1.hpp"

namespace rsfm::report {

std::string table1Csv(const Table1Result& r);
std::string table1Markdown(const Table1Result& r, const std::string& command_line);
std::string table1FigureData(const Table1Result& r);

/// Writes all outputs into dir all-or-nothing; throws std::runtime_error with a one-line
/// message (nothing is left behind on failure).
Figures writeTable1Report(const Table1Result& r, const std::filesystem::path& dir,
                       const std::string& command_line);

}  // namespace rsfm::report
