#pragma once
// `rsfm render SCENE`: rendered test sequences with known truth (docs/render.md).
//
// A scene of textured planar faces (a box on a floor, a room corner, a poster, a box moved before
// a still camera and a still wall, a box with little texture) seen by a pinhole camera with
// OpenCV's radial distortion (focal f px, principal point (cx, cy) in OpenCV's pixel-centre
// convention, k1, k2) moving along a chosen path (an orbit at a chosen speed, a translation, a
// pure rotation about the centre of projection, forward motion, none), with still stretches,
// hand-held jitter, motion blur, sensor noise and JPEG compression as options. Every face is a
// plane rendered exactly by its plane homography (cv::warpPerspective, 2x supersampled, back
// faces culled); distortion is applied by resampling an undistorted rendering that covers the
// distorted image.
// Truth: camera poses in the reference (frame 0) camera frame (rsfm::io::TumPose convention),
// relative to the scene's moving body (the object in the `object` scene, where the camera is
// still); the planes of that body in the reference frame (rsfm::io::Summary), the camera, and
// which quantities the sequence determines (render/determinacy.hpp).
// Uses OpenCV: lives in rsfm_render, never in rsfm_core.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "rsfm/io/summary.hpp"
#include "rsfm/io/tum.hpp"

namespace rsfm::render {

/// Version of the renderer's output for given options: bump it whenever a change alters the
/// pixels, the truth or the files written, so cached renderings (rsfm bench regimes) are made anew
/// (4: truth/camera.yaml).
inline constexpr int kRendererVersion = 4;

/// What is in front of the camera (docs/render.md, "Scenes").
enum class SceneKind {
  Box,         ///< a textured box standing on a textured floor
  Corner,      ///< a room corner: the floor and two walls, the camera inside
  Poster,      ///< one textured poster on an untextured wall: a single plane
  Object,      ///< a textured box moved before a still camera and a still, textured wall
  LowTexture,  ///< the box on the floor, flat-shaded, with a few small textured patches
};
/// How the camera (or, in the `object` scene, the box) moves (docs/render.md, "Motion").
enum class MotionKind {
  Orbit,      ///< a hand-held-like orbit about the scene centre (azimuth sweep, elevation, roll wobble)
  Translate,  ///< sideways translation, orientation fixed
  Rotate,     ///< pure rotation about the centre of projection (pan with a little tilt)
  Forward,    ///< along the optical axis towards the scene centre
  None,       ///< nothing moves
};
std::string_view toString(SceneKind s);
std::string_view toString(MotionKind m);
bool parseSceneKind(std::string_view s, SceneKind* out);
bool parseMotionKind(std::string_view s, MotionKind* out);
/// "box, corner, poster, object, lowtex" / "orbit, translate, rotate, forward, none".
std::string sceneKindNames();
std::string motionKindNames();

struct RenderOptions {
  SceneKind scene = SceneKind::Box;
  int frames = 150;

  // Camera (pixels, OpenCV's conventions).
  double focal_px = 520;
  int width = 640;
  int height = 480;
  /// Principal point minus the image centre ((W-1)/2, (H-1)/2), px; each within 5 % of the width.
  Eigen::Vector2d principal_offset_px = Eigen::Vector2d::Zero();
  /// Radial distortion, OpenCV's convention: x_d = x (1 + k1 r^2 + k2 r^4) in normalized coordinates.
  /// The map must stay monotonic out to the image's farthest corner (validate()).
  double k1 = 0, k2 = 0;

  // Motion.
  MotionKind motion = MotionKind::Orbit;
  /// Total sweep of the motion's angle over the moving frames (deg): the orbit's azimuth, the pan
  /// of `rotate`, the angle the translation subtends at the scene centre for `translate`.
  double orbit_deg = 36;
  /// > 0: the sweep is deg_per_frame x (moving frames - 1) instead of orbit_deg.
  double deg_per_frame = 0;
  /// Orbit elevation above the floor at the first and last moving frame (deg; linear in between,
  /// plus the hand-held wobble). Also the camera's elevation for the other motions (their mean).
  double elevation0_deg = 24, elevation1_deg = 36;
  /// Distance to the scene centre at the last moving frame relative to the first (orbit: linear
  /// in between; forward: the whole motion; unset: 1, and 0.6 for forward).
  std::optional<double> approach;
  int still_start = 0;   ///< frames added at the first pose before the motion starts
  int still_middle = 0;  ///< frames added at the pose halfway through the motion
  /// Hand-held jitter: sd of a random per-frame rotation about each axis (deg), with a camera
  /// displacement of the same angular size seen from the scene centre; 0: none.
  double jitter_deg = 0;

  // Image.
  double noise_sigma = 1.5;  ///< sensor noise, grey levels (8-bit)
  double blur = 0;           ///< motion blur: exposure as a fraction of the frame interval, [0, 1]
  /// Rolling shutter: the time from the first row's exposure to the last's, as a fraction of the
  /// frame interval, rows read top to bottom, [0, 1]; 0: a global shutter. Row y of frame k is
  /// exposed at frame time k + readout (y - (H - 1)/2) / H: the middle row at the frame's time, so
  /// pose(k) is the middle row's pose (rsfm's model, docs/estimate.md section 6).
  double readout = 0;
  int jpeg_quality = 0;      ///< 0: none; 1..100: each frame JPEG-compressed at this quality
  /// One image for every face (each box face uses a different crop; the floor tiles it whole);
  /// "procedural": seeded procedural textures; empty: photographs from the Debian package
  /// visp-images-data (folder overridable by $RSFM_VISP_IMAGES_DIR), procedural when absent.
  std::string texture;
  std::uint64_t seed = 1;  ///< wobble phases, jitter, sensor noise, procedural textures
  bool floor = true;       ///< box and lowtex scenes: the floor
  double fps = 30;

  /// The distance ratio actually used (approach, or its motion's default).
  double approachRatio() const;
  /// Frames at distinct poses (frames - still_start - still_middle).
  int movingFrames() const { return frames - still_start - still_middle; }
  /// The sweep actually used (deg).
  double sweepDeg() const;
};

/// Empty when valid, else a one-line reason naming the option.
std::string validate(const RenderOptions& o);

/// Largest distorted radius (normalized units) up to which x -> x (1 + k1 r^2 + k2 r^4) is
/// monotonic (infinity when it always is).
double monotonicDistortedRadius(double k1, double k2);

class Scene {
 public:
  /// Builds the scene and loads the textures; `note` receives one-line messages (texture
  /// fallbacks). Throws std::runtime_error when --texture cannot be read.
  explicit Scene(const RenderOptions& o, const std::function<void(const std::string&)>& note = {});
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  const RenderOptions& options() const;
  int frames() const;
  /// Camera k relative to the moving body, in the reference camera frame (t = k).
  io::TumPose pose(int k) const;
  /// The truth summary: the moving body's planes visible in at least one frame, in a fixed order,
  /// the camera (focal, principal point, distortion) and the scene size.
  io::Summary truth() const;
  /// 3x3 intrinsic matrix K.
  cv::Matx33d K() const;
  /// Frame k, 8-bit BGR, width x height, with every image effect (blur, distortion, noise, JPEG).
  /// With `labels`, a CV_8U image (at the exposure's centre): 0 background, i + 1 for pixels of
  /// truth plane i (same order as truth().planes), kStillLabel for the still body, 255 for a face
  /// of the moving body that is not in the truth (never visible enough).
  cv::Mat render(int k, cv::Mat* labels = nullptr) const;
  /// The label image of frame k alone (as render's), without rendering the frame.
  cv::Mat labels(int k) const;
  static constexpr int kStillLabel = 254;
  /// Where the scene point seen at pixel `x` of frame a (on the surface `labels_a` names there:
  /// a truth plane or the still body) appears in frame b, distortion included; nullopt on the
  /// background, behind the camera, or for a ray parallel to the surface.
  std::optional<Eigen::Vector2d> transfer(const Eigen::Vector2d& x, int a, int b, const cv::Mat& labels_a) const;
  /// Pixel of a point given in the reference camera frame (a point of the moving body when
  /// `still_body` is false, of the still body otherwise) in frame k, distortion included;
  /// nullopt behind the camera.
  std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& X_ref, int k, bool still_body = false) const;
  /// Every textured or flat face in drawing order: name, truth plane index (-1 when not in the
  /// truth), whether it belongs to the still body, and its four corners in the reference camera
  /// frame, in texture order (top-left, top-right, bottom-right, bottom-left of its picture).
  struct FacePolygon {
    std::string name;
    int truth_index = -1;
    bool still_body = false;
    bool textured = true;  ///< false: flat-shaded (nothing to track)
    std::array<Eigen::Vector3d, 4> corners;
  };
  std::vector<FacePolygon> faces() const;
  /// Where each face's texture came from ("Klimt.png", "procedural", "flat"...), in face order.
  std::vector<std::string> textureSources() const;
  /// Motion-time of frame k in [0, 1] (still frames repeat their neighbour's).
  double motionTime(int k) const;

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
/// frame count; falls back to MJPG out_dir/video.avi), out_dir/truth/trajectory.tum,
/// out_dir/truth/summary.json and out_dir/truth/render.json (the options, the determinacy analysis),
/// all-or-nothing. `out_dir` must exist and be writable. `extra` is merged into render.json
/// (e.g. the regime's name). Throws std::invalid_argument for invalid options,
/// std::runtime_error on failure.
RenderResult writeSequence(const RenderOptions& o, const std::filesystem::path& out_dir,
                           const std::function<void(int, int)>& progress = {},
                           const std::function<void(const std::string&)>& note = {},
                           const std::string& extra_json = {});

/// The options as a JSON object (every field, canonical key order; the regime suite's format).
std::string optionsToJson(const RenderOptions& o);

}  // namespace rsfm::render
