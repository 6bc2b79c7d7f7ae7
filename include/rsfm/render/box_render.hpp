#pragma once
// `rsfm render box`: a rendered test sequence with known truth (docs/render.md).
//
// A textured box standing on a textured floor, seen by a pinhole camera (focal f px, principal
// point ((W-1)/2, (H-1)/2) in OpenCV's pixel-centre convention, no distortion) moving on a
// smooth hand-held-like orbit. Every textured face is a plane, rendered exactly by its plane
// homography (cv::warpPerspective, 2x supersampled, back faces culled), plus mild sensor noise.
// Truth: camera poses in the reference (frame 0) camera frame (rsfm::io::TumPose convention) and
// the visible planes' normals and distances in that frame (rsfm::io::Summary).
// Uses OpenCV: lives in rsfm_render, never in rsfm_core.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "rsfm/io/summary.hpp"
#include "rsfm/io/tum.hpp"

namespace rsfm::render {

struct BoxRenderOptions {
  int frames = 150;
  double focal_px = 520;
  int width = 640;
  int height = 480;
  /// One image for every face (each box face uses a different crop; the floor tiles it whole);
  /// "procedural": seeded procedural textures; empty: photographs from the Debian package
  /// visp-images-data (folder overridable by $RSFM_VISP_IMAGES_DIR), procedural when absent.
  std::string texture;
  std::uint64_t seed = 1;  ///< hand-held wobble phases, sensor noise, procedural textures
  bool floor = true;
  double noise_sigma = 1.5;  ///< sensor noise, grey levels (8-bit)
  double orbit_deg = 36;     ///< azimuth swept about the box
  /// Elevation of the orbit above the floor at the first and last frame (deg; linear in between,
  /// plus the hand-held wobble). The default 24 -> 36 is the original orbit; 80 -> 50 with
  /// `approach` 0.7 starts nearly top-down and descends towards the box, as the ViSP cube does.
  double elevation0_deg = 24, elevation1_deg = 36;
  /// Orbit radius at the last frame relative to the first (linear in between; 1: constant).
  double approach = 1.0;
  double fps = 30;
};

/// Empty when valid, else a one-line reason.
std::string validate(const BoxRenderOptions& o);

class BoxScene {
 public:
  /// Builds the scene and loads the textures; `note` receives one-line messages (texture
  /// fallbacks). Throws std::runtime_error when --texture cannot be read.
  explicit BoxScene(const BoxRenderOptions& o, const std::function<void(const std::string&)>& note = {});
  ~BoxScene();
  BoxScene(const BoxScene&) = delete;
  BoxScene& operator=(const BoxScene&) = delete;

  int frames() const;
  /// Camera k in the reference camera frame (t = k).
  io::TumPose pose(int k) const;
  /// The truth summary (planes visible in at least one frame, in a fixed order).
  io::Summary truth() const;
  /// 3x3 intrinsic matrix K.
  cv::Matx33d K() const;
  /// Frame k, 8-bit BGR, width x height. With `labels`, a CV_8U image: 0 background, i + 1 for
  /// pixels of truth plane i (same order as truth().planes), 255 for a face not in the truth.
  cv::Mat render(int k, cv::Mat* labels = nullptr) const;
  /// Every textured face (floor first, then the box's front, right, top, left, back): name,
  /// truth plane index (-1 when never visible) and the four corners in the reference camera frame,
  /// in texture order (top-left, top-right, bottom-right, bottom-left of its picture).
  struct FacePolygon {
    std::string name;
    int truth_index = -1;
    std::array<Eigen::Vector3d, 4> corners;
  };
  std::vector<FacePolygon> faces() const;
  /// Where each face's texture came from ("Klimt.png", "procedural", ...), in face order.
  std::vector<std::string> textureSources() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

struct RenderResult {
  std::filesystem::path video;  ///< video.mp4 or video.avi (MJPG fallback)
  int frames = 0;
  bool mp4 = true;
  double seconds = 0;
  std::vector<std::string> notes;
};

/// Renders the sequence and writes out_dir/video.mp4 (mp4v; checked to read back with the right
/// frame count; falls back to MJPG out_dir/video.avi), out_dir/truth/trajectory.tum and
/// out_dir/truth/summary.json, all-or-nothing. `out_dir` must exist and be writable.
/// Throws std::runtime_error on failure.
RenderResult writeBoxSequence(const BoxRenderOptions& o, const std::filesystem::path& out_dir,
                              const std::function<void(int, int)>& progress = {},
                              const std::function<void(const std::string&)>& note = {});

}  // namespace rsfm::render
