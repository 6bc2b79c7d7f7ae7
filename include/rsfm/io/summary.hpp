#pragma once
// summary.json: the per-sequence summary shared by the renderer's truth and the estimator's
// output (docs/outputs.md, docs/evaluate.md). Schema (format "rsfm-summary", version 1):
//   {"format":"rsfm-summary","version":1,"frames":F,"image":{"width":W,"height":H},
//    "principal_point_px":[cx,cy],"focal_px":f,
//    "planes":[[nx,ny,nz],...],     unit normals in the reference camera frame (COP-centred,
//                                   x right, y down, z forward), pointing from the camera towards
//                                   the plane: n.X = d with d > 0
//    "plane_distances":[d,...],     trajectory units
//    "plane_tracks":[...], "plane_reprojection_rms_px":[...],   estimates only (optional)
//    "plane_names":[...], "scene_size": s,                      truth only (optional)
//    "radial_distortion":[k1,k2],   OpenCV's convention (optional; absent: none)
//    "determinable":{"focal":b,"structure":b,"why":"...","crb_focal_rel_sd":x|null,
//                    "crb_normal_sd_deg":[...]|null}   truth only (optional; docs/render.md)}
// Pixel coordinates follow OpenCV: integer values at pixel centres, (0,0) = top-left pixel.
// "focal_px" may be null (unknown). Unknown keys are kept out of the struct but allowed.
#include <Eigen/Core>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "rsfm/io/input_error.hpp"

namespace rsfm::io {

/// Which quantities a (rendered) sequence determines: from the Cramer-Rao bound of the plane
/// model's batch problem at the truth (render/determinacy.hpp; limits in rsfm/determinacy.hpp).
struct Determinable {
  bool focal = true;      ///< the focal length
  bool structure = true;  ///< the plane normals and distances (and the translation's direction)
  std::string why;        ///< one line: what the analysis found
  std::optional<double> crb_focal_rel_sd;        ///< sd(f)/f at the bound; absent when rank-deficient
  std::vector<std::optional<double>> crb_normal_sd_deg;  ///< per truth plane; nullopt: not analysed / not determined
};

struct Summary {
  int frames = 0;
  int width = 0;
  int height = 0;
  Eigen::Vector2d principal_point_px = Eigen::Vector2d::Zero();
  std::optional<double> focal_px;
  std::vector<Eigen::Vector3d> planes;          ///< unit normals, reference camera frame
  std::vector<double> plane_distances;          ///< same order as planes
  std::vector<int> plane_tracks;                ///< estimates: tracks per plane (may be empty)
  std::vector<double> plane_reprojection_rms_px;///< estimates (may be empty)
  std::vector<std::string> plane_names;         ///< truth (may be empty)
  std::optional<double> scene_size;             ///< truth: scene size in trajectory units
  /// The frame rate the trajectory's timestamps are in (seconds = frame / fps); unset: the
  /// timestamps are frame numbers (docs/outputs.md, docs/evaluate.md).
  std::optional<double> fps;
  /// With fps: the time of frame 0 in seconds (`time_origin_s`; images named by their
  /// timestamps), the timestamps being time_origin + frame / fps; 0 when absent.
  double time_origin = 0.0;
  std::vector<int> plane_visible_frames;        ///< truth: frames in which each plane is visible (may be empty)
  std::optional<Eigen::Vector2d> distortion;    ///< radial (k1, k2), OpenCV's convention
  std::optional<Determinable> determinable;     ///< truth: what the sequence determines
};

/// Reads and checks a summary.json. Throws InputError ("FILE:LINE: ..." for JSON syntax errors,
/// "FILE: ..." for a missing or invalid key).
Summary readSummary(const std::filesystem::path& file);
/// The same from the file's text (`file` names it in messages).
Summary readSummaryText(const std::string& text, const std::filesystem::path& file);
/// The largest summary.json read (bytes): a summary is a few kB.
inline constexpr std::size_t kMaxSummaryBytes = 16u << 20;

/// The JSON text (2-space indented, keys in the schema's order; optional parts omitted when empty).
std::string summaryToJson(const Summary& s);

}  // namespace rsfm::io
