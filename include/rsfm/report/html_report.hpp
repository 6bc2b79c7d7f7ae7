#pragma once
// report.html (issue 16; docs/outputs.md, "report.html"): one self-contained page per
// `rsfm run` / `rsfm estimate` that ties the run's files together: what the data did not
// determine and every warning first, then the main figures (focal length, planes, angles, the
// camera), the plots embedded as PNG data, a poster frame of the overlay linking to the video,
// the whole summary.json as tables, and the list of files. No script, no external resource:
// it reads offline and from a copied directory.
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace rsfm::report {

struct HtmlReport {
  std::string title;                 ///< e.g. "rsfm run box.mp4"
  nlohmann::json summary;            ///< what summary.json holds
  /// Figures to embed: (caption, PNG file). Read when the page is made (temporaries are fine).
  std::vector<std::pair<std::string, std::filesystem::path>> figures;
  std::string figures_note;          ///< why there are no figures (e.g. "--no-plots"), or ""
  std::vector<std::string> warnings;  ///< one line each
  std::vector<unsigned char> poster_png;  ///< a frame of the overlay (PNG), or empty
  std::string overlay_file;          ///< "overlay.mp4" when written, else ""
  std::string overlay_codec;         ///< "h264" / "mpeg4"
  std::vector<std::string> files;    ///< the files of the output directory, for links
};

/// The findings a reader must not miss, from a summary (plane or patch pipeline): every quantity
/// the data did not determine, with the interval that is supported where there is one, and a
/// run that ended early. One line each.
std::vector<std::string> notDeterminedFindings(const nlohmann::json& summary);

/// The page (UTF-8 HTML5). A figure file that cannot be read is named in the page instead.
std::string htmlReport(const HtmlReport& r);

/// RFC 4648 base64 of `data`.
std::string base64(const unsigned char* data, std::size_t size);

}  // namespace rsfm::report
