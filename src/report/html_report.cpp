#include "rsfm/report/html_report.hpp"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include "rsfm/io/json_text.hpp"

namespace rsfm::report {

namespace {

std::string esc(const std::string& s) {
  std::string o;
  o.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&': o += "&amp;"; break;
      case '<': o += "&lt;"; break;
      case '>': o += "&gt;"; break;
      case '"': o += "&quot;"; break;
      case '\'': o += "&#39;"; break;
      default: o += c;
    }
  }
  return o;
}

bool isNum(const nlohmann::json& j, const char* key) { return j.contains(key) && j[key].is_number(); }
double num(const nlohmann::json& j, const char* key) { return j[key].get<double>(); }

std::string fmtNum(double v) {
  if (!std::isfinite(v)) return "not finite";
  const double a = std::abs(v);
  if (a != 0 && (a < 1e-3 || a >= 1e7)) return fmt::format("{:.4g}", v);
  return fmt::format("{:.6g}", v);
}

/// Any JSON value as HTML: objects and arrays of objects as tables, arrays of scalars inline.
std::string jsonHtml(const nlohmann::json& j, int depth = 0) {
  if (j.is_null()) return "<span class=\"nd\">null</span>";
  if (j.is_boolean()) return j.get<bool>() ? "true" : "<b>false</b>";
  if (j.is_number()) return esc(fmtNum(j.get<double>()));
  if (j.is_string()) return esc(j.get<std::string>());
  if (j.is_array()) {
    bool scalars = true;
    for (const auto& e : j) scalars = scalars && !e.is_object() && !e.is_array();
    if (scalars || depth > 3) {
      std::string o = "[";
      for (size_t i = 0; i < j.size(); ++i) o += (i ? ", " : "") + jsonHtml(j[i], depth + 1);
      return o + "]";
    }
    std::string o = "<ol start=\"0\">";
    for (const auto& e : j) o += "<li>" + jsonHtml(e, depth + 1) + "</li>";
    return o + "</ol>";
  }
  std::string o = "<table class=\"kv\">";
  for (const auto& [k, v] : j.items()) o += "<tr><th>" + esc(k) + "</th><td>" + jsonHtml(v, depth + 1) + "</td></tr>";
  return o + "</table>";
}

std::string readFile(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw std::runtime_error("report.html: cannot read " + p.string());
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::string vec3(const nlohmann::json& v) {
  if (!v.is_array() || v.size() != 3) return jsonHtml(v);
  return fmt::format("({:.4f}, {:.4f}, {:.4f})", v[0].get<double>(), v[1].get<double>(), v[2].get<double>());
}

/// The main figures as one table.
std::string headline(const nlohmann::json& s) {
  std::string o = "<table class=\"main\">";
  auto row = [&](const std::string& k, const std::string& v) { o += "<tr><th>" + esc(k) + "</th><td>" + v + "</td></tr>"; };
  if (s.contains("model")) row("model", jsonHtml(s["model"]));
  if (s.contains("frames"))
    row("frames", fmt::format("{} ({}&ndash;{})", s["frames"].dump(), s.value("first_frame", 0), s.value("last_frame", 0)));
  if (s.contains("image") && s["image"].is_object())
    row("image", fmt::format("{} &times; {} px", s["image"].value("width", 0), s["image"].value("height", 0)));
  if (s.contains("focal_px")) {
    if (s["focal_px"].is_null()) {
      std::string v = "<span class=\"nd\">not determined</span>";
      if (s.contains("focal_interval_px") && s["focal_interval_px"].is_array() && s["focal_interval_px"].size() == 2)
        v += fmt::format(" (the data support {})", io::focalIntervalText(s["focal_interval_px"], "&ndash;"));
      row("focal length", v);
    } else if (s.contains("focal_given")) {
      row("focal length", fmt::format("{:.1f} px (given)", num(s, "focal_px")));
    } else {
      row("focal length", fmt::format("{:.1f} &plusmn; {} px", num(s, "focal_px"),
                                      isNum(s, "focal_sd_px") ? fmt::format("{:.1f}", num(s, "focal_sd_px")) : "?"));
    }
  }
  if (s.contains("principal_point_px") && s["principal_point_px"].is_array())
    row("principal point", fmt::format("({:.1f}, {:.1f}) px", s["principal_point_px"][0].get<double>(),
                                       s["principal_point_px"][1].get<double>()));
  if (s.contains("planes") && s["planes"].is_array()) {
    std::string t = "<table class=\"inner\"><tr><th>plane</th><th>unit normal (first camera frame)</th><th>normal sd</th>"
                    "<th>distance</th><th>tracks</th></tr>";
    for (size_t j = 0; j < s["planes"].size(); ++j) {
      const bool det = !s.contains("plane_determined") || !s["plane_determined"].is_array() ||
                       j >= s["plane_determined"].size() || s["plane_determined"][j].get<bool>();
      auto at = [&](const char* key) -> std::string {
        if (!s.contains(key) || !s[key].is_array() || j >= s[key].size()) return "";
        const auto& v = s[key][j];
        return v.is_null() ? "<span class=\"nd\">not determined</span>" : jsonHtml(v);
      };
      std::string sd = at("plane_normal_sd_deg");
      if (!sd.empty() && s["plane_normal_sd_deg"][j].is_number())
        sd = fmt::format("{:.2f}&deg;", s["plane_normal_sd_deg"][j].get<double>());
      t += fmt::format("<tr><td>{}</td><td>{}{}</td><td>{}</td><td>{}</td><td>{}</td></tr>", j, vec3(s["planes"][j]),
                       det ? "" : " <span class=\"nd\">(not determined)</span>", sd, at("plane_distances"), at("plane_tracks"));
    }
    row("planes", t + "</table>");
  }
  if (s.contains("angles_between_planes_deg"))
    for (const auto& a : s["angles_between_planes_deg"]) {
      const bool det = !a.contains("determined") || a["determined"].get<bool>();
      // With its sd and 95 % interval when the summary has them (planeAngle).
      const bool has_sd = a.contains("sd_deg") && a["sd_deg"].is_number() && a.contains("interval_deg") && a["interval_deg"].is_array();
      const std::string sd = has_sd ? fmt::format(" &plusmn; {:.2f}&deg; (95 %: {:.1f}&ndash;{:.1f}&deg;)", a["sd_deg"].get<double>(),
                                                  a["interval_deg"][0].get<double>(), a["interval_deg"][1].get<double>())
                                    : std::string();
      row(fmt::format("angle between planes {} and {}", a["planes"][0].get<int>(), a["planes"][1].get<int>()),
          fmt::format("{:.2f}&deg;{}{}", a["angle_deg"].get<double>(), sd, det ? "" : " <span class=\"nd\">(not determined)</span>"));
    }
  if (s.contains("last_frame_normals") && s["last_frame_normals"].is_object()) {
    const auto& ln = s["last_frame_normals"];
    row("patch normals (last frame)", fmt::format("{} within 5&deg; of their median", ln.value("within_5deg", 0)));
  }
  if (s.contains("tracks") && s["tracks"].is_object()) row("tracks", jsonHtml(s["tracks"]));
  if (isNum(s, "seconds")) {
    std::string stages;
    if (s.contains("stage_seconds") && s["stage_seconds"].is_object())
      for (const char* k : {"tracking", "plane_finding", "start", "filter", "refinement"})
        if (isNum(s["stage_seconds"], k))
          stages += fmt::format("{}{} {:.2f} s", stages.empty() ? " (" : ", ", k, num(s["stage_seconds"], k));
    row("run time", fmt::format("{:.2f} s{}", num(s, "seconds"), stages.empty() ? "" : stages + ")"));
  }
  if (s.contains("command")) row("command", "<code>" + esc(s["command"].get<std::string>()) + "</code>");
  return o + "</table>";
}

const char* kStyle = R"(body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.5em}
.box{border-radius:6px;padding:.6em 1em;margin:.6em 0}.warn{background:#fff3cd;border:1px solid #e0b000}
.ndbox{background:#fde2e1;border:1px solid #d9534f}.ok{background:#e6f4ea;border:1px solid #5cb85c}
.nd{color:#b00020;font-weight:bold}table{border-collapse:collapse}th,td{text-align:left;vertical-align:top;padding:2px 8px}
table.main>tbody>tr>th,table.main>tr>th{white-space:nowrap}table.inner td,table.inner th{border:1px solid #ddd}
table.kv{border-left:2px solid #eee;margin:2px 0}table.kv th{font-weight:normal;color:#555}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}figcaption{color:#555}
code{background:#f4f4f4;padding:0 3px}details{margin:1em 0}summary{cursor:pointer;font-weight:bold})";

}  // namespace

std::string base64(const unsigned char* data, std::size_t size) {
  static const char* tab = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string o;
  o.reserve((size + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < size; i += 3) {
    const unsigned v = (data[i] << 16) | (data[i + 1] << 8) | data[i + 2];
    o += tab[(v >> 18) & 63];
    o += tab[(v >> 12) & 63];
    o += tab[(v >> 6) & 63];
    o += tab[v & 63];
  }
  if (i < size) {
    const unsigned v = (data[i] << 16) | (i + 1 < size ? data[i + 1] << 8 : 0);
    o += tab[(v >> 18) & 63];
    o += tab[(v >> 12) & 63];
    o += i + 1 < size ? tab[(v >> 6) & 63] : '=';
    o += '=';
  }
  return o;
}

std::vector<std::string> notDeterminedFindings(const nlohmann::json& s) {
  std::vector<std::string> out;
  if (s.contains("focal_px") && s["focal_px"].is_null() && !s.contains("focal_given")) {
    std::string f = "Focal length not determined";
    if (s.contains("focal_interval_px") && s["focal_interval_px"].is_array() && s["focal_interval_px"].size() == 2)
      f += fmt::format(": the data support {}", io::focalIntervalText(s["focal_interval_px"]));
    out.push_back(f + ".");
  }
  if (s.contains("structure_determined") && s["structure_determined"].is_boolean() && !s["structure_determined"].get<bool>())
    out.push_back("The structure (plane or patch normals) is not determined by these data.");
  if (s.contains("plane_determined") && s["plane_determined"].is_array())
    for (size_t j = 0; j < s["plane_determined"].size(); ++j)
      if (s["plane_determined"][j].is_boolean() && !s["plane_determined"][j].get<bool>())
        out.push_back(fmt::format("Plane {} is not determined (its normal and distance have no supported value).", j));
  if (s.contains("angles_between_planes_deg"))
    for (const auto& a : s["angles_between_planes_deg"])
      if (a.contains("determined") && !a["determined"].get<bool>())
        out.push_back(fmt::format("The angle between planes {} and {} is not determined.", a["planes"][0].get<int>(),
                                  a["planes"][1].get<int>()));
  if (s.contains("not_determined_why") && s["not_determined_why"].is_string() && !s["not_determined_why"].get<std::string>().empty())
    out.push_back("Not determined: " + s["not_determined_why"].get<std::string>() + ".");
  if (s.contains("ended_early") && s["ended_early"].is_string() && !s["ended_early"].get<std::string>().empty())
    out.push_back("The run ended early: " + s["ended_early"].get<std::string>());
  if (s.contains("pass_stopped") && s["pass_stopped"].is_string() && !s["pass_stopped"].get<std::string>().empty())
    out.push_back("The filter's " + s["pass_stopped"].get<std::string>() + ".");
  return out;
}

std::string htmlReport(const HtmlReport& r) {
  std::string o = "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>" + esc(r.title) +
                  "</title>\n<meta name=\"generator\" content=\"rsfm\">\n<style>" + kStyle + "</style></head>\n<body>\n";
  o += "<h1>" + esc(r.title) + "</h1>\n";
  // What a reader must not miss, first.
  const std::vector<std::string> nd = notDeterminedFindings(r.summary);
  if (!nd.empty()) {
    o += "<div class=\"box ndbox\" id=\"not-determined\"><b>What these data do not determine</b><ul>";
    for (const auto& l : nd) o += "<li>" + esc(l) + "</li>";
    o += "</ul></div>\n";
  }
  if (!r.warnings.empty()) {
    o += "<div class=\"box warn\" id=\"warnings\"><b>Warnings</b><ul>";
    for (const auto& w : r.warnings) o += "<li>" + esc(w) + "</li>";
    o += "</ul></div>\n";
  }
  if (nd.empty() && r.warnings.empty())
    o += "<div class=\"box ok\" id=\"no-findings\">Every reported quantity is determined by the data; no warnings.</div>\n";
  o += "<h2>Result</h2>\n" + headline(r.summary) + "\n";
  o += "<h2>Figures</h2>\n";
  if (r.figures.empty()) o += "<p>No figures" + (r.figures_note.empty() ? std::string() : ": " + esc(r.figures_note)) + ".</p>\n";
  for (const auto& [caption, file] : r.figures) {
    std::string png;
    try {
      png = readFile(file);
    } catch (const std::exception& e) {
      o += "<p class=\"nd\">" + esc(caption) + ": " + esc(e.what()) + "</p>\n";
      continue;
    }
    o += "<figure><img alt=\"" + esc(caption) + "\" src=\"data:image/png;base64," +
         base64(reinterpret_cast<const unsigned char*>(png.data()), png.size()) + "\"><figcaption>" + esc(caption) +
         "</figcaption></figure>\n";
  }
  if (!r.overlay_file.empty()) {
    o += "<h2>Overlay video</h2>\n<p><a href=\"" + esc(r.overlay_file) + "\">" + esc(r.overlay_file) + "</a> (" +
         (r.overlay_codec == "h264" ? std::string("H.264, plays in a browser") : esc(r.overlay_codec)) +
         "): tracks coloured by plane, outliers as red crosses, each plane drawn as a grid with that frame's estimate.</p>\n";
    if (!r.poster_png.empty())
      o += "<figure><a href=\"" + esc(r.overlay_file) + "\"><img alt=\"overlay poster frame\" src=\"data:image/png;base64," +
           base64(r.poster_png.data(), r.poster_png.size()) + "\"></a><figcaption>The middle frame of the overlay (click for the video)."
           "</figcaption></figure>\n";
  }
  o += "<h2>Summary</h2>\n<details><summary>summary.json, every field (docs/outputs.md)</summary>\n" + jsonHtml(r.summary) +
       "\n</details>\n";
  if (!r.files.empty()) {
    o += "<h2>Files</h2>\n<ul>";
    for (const auto& f : r.files) o += "<li><a href=\"" + esc(f) + "\">" + esc(f) + "</a></li>";
    o += "</ul>\n";
  }
  o += "</body></html>\n";
  return o;
}

}  // namespace rsfm::report
