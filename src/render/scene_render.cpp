#include "rsfm/render/scene_render.hpp"
#include "rsfm/units.hpp"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <stdexcept>

#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/camera_yaml.hpp"
#include "rsfm/models/radial_camera.hpp"
#include "rsfm/render/determinacy.hpp"

namespace rsfm::render {
namespace fs = std::filesystem;
using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

const char* kVispRoot = "/usr/share/visp-images-data/ViSP-images/";

// The photographs' folder: $RSFM_VISP_IMAGES_DIR if set (tests use it to exercise the fallback),
// else the Debian package's.
std::string vispRoot() {
  const char* env = std::getenv("RSFM_VISP_IMAGES_DIR");
  if (env && *env) return std::string(env) + "/";
  return kVispRoot;
}

// Box (world frame: y up, box standing on the floor y = 0, centred on the y axis).
constexpr double kBoxX = 1.0, kBoxY = 0.7, kBoxZ = 0.8;
constexpr double kFloorHalf = 2.5;  // floor square half-side
constexpr int kFloorCells = 8;      // floor split into cells, each with its own texture level
constexpr double kNear = 0.02;      // near clipping depth
// Room corner: floor y = 0 and walls x = 0, z = 0 over [0, kRoom] (height kRoomH).
constexpr double kRoom = 4.0, kRoomH = 2.6;
// Poster on the wall z = 0: x in [-0.8, 0.8], y in [0.2, 1.4]; the wall around it is untextured.
constexpr double kPosterW = 1.6, kPosterH = 1.2, kPosterY0 = 0.2;

constexpr std::array<std::string_view, 5> kSceneNames{"box", "corner", "poster", "object", "lowtex"};
constexpr std::array<std::string_view, 5> kMotionNames{"orbit", "translate", "rotate", "forward", "none"};

struct Texture {
  std::vector<cv::Mat> pyr;  // level 0 = full resolution, BGR 8-bit
  std::string source;
};

struct Face {
  std::string name;
  std::string plane;           // truth plane (faces of one plane share it)
  bool still = false;          // belongs to the still body (fixed to the camera: the object scene's wall)
  Vector3d P0, Eu, Ev, n_out;  // corner, edges (texture u right, v down), outward normal (world)
  double rep_u = 1, rep_v = 1; // texture repetitions along Eu, Ev
  int texture = -1;            // -1: flat colour
  cv::Scalar flat;             // flat colour (BGR) when texture < 0
  int border = cv::BORDER_REPLICATE;
  double shade = 1;
  int truth_index = -1;
  std::vector<std::array<Vector3d, 4>> cells;  // polygons to draw (one, or a grid)
};

cv::Mat proceduralTexture(std::uint64_t seed, int size) {
  cv::RNG rng(seed * 2654435761ULL + 12345);
  cv::Mat acc(size, size, CV_32FC3, cv::Scalar::all(0));
  double w = 1, wsum = 0;
  for (int cells = 4; cells <= size / 2; cells *= 2) {
    cv::Mat small(cells, cells, CV_32FC3);
    rng.fill(small, cv::RNG::UNIFORM, 0.0, 1.0);
    cv::Mat big;
    cv::resize(small, big, acc.size(), 0, 0, cv::INTER_CUBIC);
    acc += big * w;
    wsum += w;
    w *= 0.75;
  }
  acc /= wsum;
  cv::Mat img;
  acc.convertTo(img, CV_8UC3, 255.0 * 1.6, -255.0 * 0.3);
  for (int i = 0; i < 60; ++i) {  // shapes with sharp corners
    const cv::Scalar c(rng.uniform(0, 256), rng.uniform(0, 256), rng.uniform(0, 256));
    const cv::Point p(rng.uniform(0, size), rng.uniform(0, size));
    const int r = rng.uniform(size / 60, size / 12);
    if (i % 2)
      cv::rectangle(img, p, p + cv::Point(r, rng.uniform(r / 2, 2 * r)), c, cv::FILLED);
    else
      cv::circle(img, p, r, c, cv::FILLED, cv::LINE_AA);
  }
  return img;
}

cv::Mat cropToAspect(const cv::Mat& img, double aspect, double fx, double fy, double frac) {
  // Largest window of the given aspect (w/h) covering `frac` of the image, at relative offset (fx, fy).
  double w = img.cols * frac, h = w / aspect;
  if (h > img.rows * frac) {
    h = img.rows * frac;
    w = h * aspect;
  }
  const int iw = std::max(8, static_cast<int>(w)), ih = std::max(8, static_cast<int>(h));
  const int x = static_cast<int>(fx * (img.cols - iw)), y = static_cast<int>(fy * (img.rows - ih));
  return img(cv::Rect(x, y, std::min(iw, img.cols), std::min(ih, img.rows))).clone();
}

Texture makeTexture(cv::Mat img, std::string source) {
  Texture t;
  t.source = std::move(source);
  t.pyr.push_back(img);
  while (t.pyr.back().cols > 16 && t.pyr.back().rows > 16 && t.pyr.size() < 8) {
    cv::Mat d;
    cv::pyrDown(t.pyr.back(), d);
    t.pyr.push_back(d);
  }
  return t;
}

// Sutherland-Hodgman clip of a polygon (camera coordinates) to z >= kNear.
std::vector<Vector3d> clipNear(const std::vector<Vector3d>& poly) {
  std::vector<Vector3d> out;
  for (std::size_t i = 0; i < poly.size(); ++i) {
    const Vector3d& a = poly[i];
    const Vector3d& b = poly[(i + 1) % poly.size()];
    const bool ia = a.z() >= kNear, ib = b.z() >= kNear;
    if (ia) out.push_back(a);
    if (ia != ib) out.push_back(a + (b - a) * ((kNear - a.z()) / (b.z() - a.z())));
  }
  return out;
}

// Sets the pixels of `img` whose centres (integer coordinates) lie inside the convex polygon
// `pts` (given in img's coordinates) to `value`. (cv::fillConvexPoly includes every pixel within
// half a pixel of the outline, which would grow each face by half a supersampled pixel.)
void fillConvexExact(cv::Mat& img, const std::vector<cv::Point2d>& pts, const cv::Scalar& value) {
  const std::size_t n = pts.size();
  if (n < 3) return;
  double area2 = 0;
  for (std::size_t i = 0; i < n; ++i) area2 += pts[i].cross(pts[(i + 1) % n]);
  if (area2 == 0) return;
  const double sgn = area2 > 0 ? 1.0 : -1.0;
  double ymin = pts[0].y, ymax = pts[0].y;
  for (const auto& p : pts) {
    ymin = std::min(ymin, p.y);
    ymax = std::max(ymax, p.y);
  }
  const int y0 = std::max(0, static_cast<int>(std::ceil(ymin))), y1 = std::min(img.rows - 1, static_cast<int>(std::floor(ymax)));
  for (int y = y0; y <= y1; ++y) {
    double lo = -1e300, hi = 1e300;
    bool empty = false;
    for (std::size_t i = 0; i < n && !empty; ++i) {
      // Inside: cross(b - a, p - a) has the polygon's orientation sign.
      const cv::Point2d& a = pts[i];
      const cv::Point2d& b = pts[(i + 1) % n];
      const double ex = b.x - a.x, ey = b.y - a.y;
      // sgn * (ex (y - a.y) - ey (x - a.x)) >= 0
      const double k = -sgn * ey, c0 = sgn * (ex * (y - a.y) + ey * a.x);
      if (k > 0)
        lo = std::max(lo, -c0 / k);
      else if (k < 0)
        hi = std::min(hi, -c0 / k);
      else if (c0 < 0)
        empty = true;
    }
    if (empty) continue;
    const int x0 = static_cast<int>(std::max(0.0, std::ceil(std::max(lo, -1.0))));
    const int x1 = static_cast<int>(std::min(static_cast<double>(img.cols - 1), std::floor(std::min(hi, 1e9))));
    if (x1 >= x0) img.row(y).colRange(x0, x1 + 1).setTo(value);
  }
}

cv::Matx33d toCv(const Matrix3d& m) {
  cv::Matx33d r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r(i, j) = m(i, j);
  return r;
}

// Camera orientation (columns: camera x, y, z in the world) looking from C at `target`, world y
// up, rolled by `roll` about the optical axis.
Matrix3d lookAt(const Vector3d& C, const Vector3d& target, double roll) {
  const Vector3d z = (target - C).normalized();
  const Vector3d x = z.cross(Vector3d::UnitY()).normalized();
  const Vector3d y = z.cross(x);
  Matrix3d R;
  R.col(0) = std::cos(roll) * x + std::sin(roll) * y;
  R.col(1) = -std::sin(roll) * x + std::cos(roll) * y;
  R.col(2) = z;
  return R;
}

// Undistorted radius (pinhole units) of a distorted one inside the monotonic range.
double undistortRadius(double rd, double k1, double k2) {
  Eigen::Vector2d h;
  if (!RadialCamera::invert(Eigen::Vector4d(0, 0, k1, k2), 1.0, Eigen::Vector2d(rd, 0), &h)) return rd;
  return h.x();
}

}  // namespace

std::string_view toString(SceneKind s) { return kSceneNames[static_cast<int>(s)]; }
std::string_view toString(MotionKind m) { return kMotionNames[static_cast<int>(m)]; }

bool parseSceneKind(std::string_view s, SceneKind* out) {
  for (std::size_t i = 0; i < kSceneNames.size(); ++i)
    if (kSceneNames[i] == s) {
      *out = static_cast<SceneKind>(i);
      return true;
    }
  return false;
}

bool parseMotionKind(std::string_view s, MotionKind* out) {
  for (std::size_t i = 0; i < kMotionNames.size(); ++i)
    if (kMotionNames[i] == s) {
      *out = static_cast<MotionKind>(i);
      return true;
    }
  return false;
}

std::string sceneKindNames() {
  std::string r;
  for (auto n : kSceneNames) r += (r.empty() ? "" : ", ") + std::string(n);
  return r;
}

std::string motionKindNames() {
  std::string r;
  for (auto n : kMotionNames) r += (r.empty() ? "" : ", ") + std::string(n);
  return r;
}

double RenderOptions::approachRatio() const {
  if (approach) return *approach;
  return motion == MotionKind::Forward ? 0.6 : 1.0;
}

double RenderOptions::sweepDeg() const {
  return deg_per_frame > 0 ? deg_per_frame * (movingFrames() - 1) : orbit_deg;
}

double monotonicDistortedRadius(double k1, double k2) { return RadialCamera::monotonicRadius(k1, k2); }

std::string validate(const RenderOptions& o) {
  if (o.frames < 2 || o.frames > 100000) return fmt::format("--frames must be in [2, 100000], got {}", o.frames);
  if (o.width < 64 || o.height < 48 || o.width > 8192 || o.height > 8192)
    return fmt::format("--width/--height must be in [64, 8192] x [48, 8192], got {}x{}", o.width, o.height);
  if (o.width % 2 || o.height % 2) return fmt::format("--width and --height must be even (video), got {}x{}", o.width, o.height);
  if (!std::isfinite(o.focal_px) || o.focal_px <= 0)
    return fmt::format("--focal-px must be a positive number of pixels, got {}", o.focal_px);
  if (o.focal_px < 0.3 * o.width || o.focal_px > 10.0 * o.width)
    return fmt::format("--focal-px must be in [0.3, 10] x width = [{}, {}], got {}", 0.3 * o.width, 10.0 * o.width,
                       o.focal_px);
  const double pp_lim = 0.05 * o.width;
  if (!o.principal_offset_px.allFinite() || std::abs(o.principal_offset_px.x()) > pp_lim ||
      std::abs(o.principal_offset_px.y()) > pp_lim)
    return fmt::format("--principal-offset must be within 5 % of the width (|dx|, |dy| <= {} px), got {},{}", pp_lim,
                       o.principal_offset_px.x(), o.principal_offset_px.y());
  if (!std::isfinite(o.k1) || !std::isfinite(o.k2) || std::abs(o.k1) > 1 || std::abs(o.k2) > 1)
    return fmt::format("--k1 and --k2 must be in [-1, 1], got {}, {}", o.k1, o.k2);
  {
    // The distortion must be monotonic (invertible) out to the farthest image corner, with a
    // margin: that corner's distorted radius within 95 % of the largest one reached monotonically.
    const double cx = 0.5 * (o.width - 1) + o.principal_offset_px.x(), cy = 0.5 * (o.height - 1) + o.principal_offset_px.y();
    double rc = 0;
    for (double x : {-0.5, o.width - 0.5})
      for (double y : {-0.5, o.height - 0.5}) rc = std::max(rc, std::hypot(x - cx, y - cy) / o.focal_px);
    const double rm = monotonicDistortedRadius(o.k1, o.k2);
    if (rc > 0.95 * rm)
      return fmt::format(
          "--k1 {} --k2 {} fold the image: the distortion is monotonic only out to a radius of {:.3f} focal lengths "
          "but the farthest corner is at {:.3f} (needs <= 95 % of it); use a smaller |k1| or a longer focal length",
          o.k1, o.k2, rm, rc);
  }
  if (o.still_start < 0 || o.still_middle < 0)
    return fmt::format("--still-start and --still-middle must be >= 0, got {}, {}", o.still_start, o.still_middle);
  if (o.movingFrames() < 2)
    return fmt::format("the still stretches ({} + {} frames) leave fewer than 2 moving frames of the {}", o.still_start,
                       o.still_middle, o.frames);
  if (!std::isfinite(o.orbit_deg) || o.orbit_deg < 0 || o.orbit_deg > 360)
    return fmt::format("--orbit-deg must be in [0, 360], got {}", o.orbit_deg);
  if (!std::isfinite(o.deg_per_frame) || o.deg_per_frame < 0 || o.deg_per_frame > 30)
    return fmt::format("--deg-per-frame must be in [0, 30], got {}", o.deg_per_frame);
  if (o.sweepDeg() > 360)
    return fmt::format("--deg-per-frame {} over {} moving frames sweeps {:.0f} deg (at most 360)", o.deg_per_frame,
                       o.movingFrames(), o.sweepDeg());
  for (double e : {o.elevation0_deg, o.elevation1_deg})
    if (!std::isfinite(e) || e < 5 || e > 85) return fmt::format("--elevation values must be in [5, 85] deg, got {}", e);
  if (o.approach && (!std::isfinite(*o.approach) || *o.approach < 0.3 || *o.approach > 3))
    return fmt::format("--approach must be in [0.3, 3], got {}", *o.approach);
  if (o.motion == MotionKind::Forward && o.approachRatio() == 1.0)
    return "--motion forward needs --approach other than 1 (the final distance relative to the first)";
  if (!std::isfinite(o.jitter_deg) || o.jitter_deg < 0 || o.jitter_deg > 5)
    return fmt::format("--jitter-deg must be in [0, 5], got {}", o.jitter_deg);
  if (!std::isfinite(o.noise_sigma) || o.noise_sigma < 0 || o.noise_sigma > 50)
    return fmt::format("--noise must be in [0, 50] grey levels, got {}", o.noise_sigma);
  if (!std::isfinite(o.blur) || o.blur < 0 || o.blur > 1)
    return fmt::format("--blur must be in [0, 1] (exposure / frame interval), got {}", o.blur);
  if (!std::isfinite(o.readout) || o.readout < 0 || o.readout > 1)
    return fmt::format("--readout must be in [0, 1] (the rolling shutter's readout / frame interval), got {}", o.readout);
  if (o.jpeg_quality < 0 || o.jpeg_quality > 100)
    return fmt::format("--jpeg-quality must be in [0, 100] (0: none), got {}", o.jpeg_quality);
  if (!std::isfinite(o.fps) || o.fps <= 0 || o.fps > 240) return fmt::format("--fps must be in (0, 240], got {}", o.fps);
  if (!o.floor && o.scene != SceneKind::Box && o.scene != SceneKind::LowTexture)
    return fmt::format("--no-floor applies to the box and lowtex scenes, not {}", toString(o.scene));
  if (!o.texture.empty() && o.texture != "procedural") {
    std::error_code ec;
    if (!fs::is_regular_file(o.texture, ec)) return "--texture " + o.texture + ": no such file";
    const cv::Mat img = cv::imread(o.texture, cv::IMREAD_COLOR);
    if (img.empty() || img.cols < 16 || img.rows < 16)
      return "--texture " + o.texture + ": not an image OpenCV can read, or smaller than 16x16 pixels";
  }
  return {};
}

std::string optionsToJson(const RenderOptions& o) {
  nlohmann::ordered_json j;
  j["scene"] = toString(o.scene);
  j["frames"] = o.frames;
  j["focal_px"] = o.focal_px;
  j["width"] = o.width;
  j["height"] = o.height;
  j["principal_offset_px"] = {o.principal_offset_px.x(), o.principal_offset_px.y()};
  j["k1"] = o.k1;
  j["k2"] = o.k2;
  j["motion"] = toString(o.motion);
  j["orbit_deg"] = o.orbit_deg;
  j["deg_per_frame"] = o.deg_per_frame;
  j["elevation_deg"] = {o.elevation0_deg, o.elevation1_deg};
  j["approach"] = o.approach ? nlohmann::ordered_json(*o.approach) : nlohmann::ordered_json(nullptr);
  j["still_start"] = o.still_start;
  j["still_middle"] = o.still_middle;
  j["jitter_deg"] = o.jitter_deg;
  j["noise"] = o.noise_sigma;
  j["blur"] = o.blur;
  // Written only for a rolling shutter: the global-shutter sequences' canonical text (and the
  // regime cache's keys, hashed from it) stay what they were before the option existed.
  if (o.readout != 0) j["readout"] = o.readout;
  j["jpeg_quality"] = o.jpeg_quality;
  j["texture"] = o.texture;
  j["seed"] = o.seed;
  j["floor"] = o.floor;
  j["fps"] = o.fps;
  return j.dump();
}

// ---------------------------------------------------------------------------------------------
struct Scene::Impl {
  RenderOptions o;
  std::vector<Texture> textures;
  std::vector<Face> faces;  // painter's order
  // The path: moving poses j = 0..n-1 (camera -> world of the moving body), and the still body's
  // camera pose (the first moving pose).
  Vector3d centre;          // scene centre the camera looks at
  double r0 = 1;            // camera distance to the centre
  double az0_deg = 45;      // azimuth of the rig (from +z towards +x)
  double ph[8] = {};        // wobble phases
  std::vector<Vector3d> jit_rot, jit_pos;  // per moving frame
  std::vector<Matrix3d> Rwc;  // per frame (exposure centre)
  std::vector<Vector3d> C;    // per frame
  std::vector<double> tau;    // per frame: motion time
  std::vector<bool> added_still;  // per frame: an added still frame (a repeat of the previous pose)
  io::Summary truth;
  Eigen::Vector2d pp;       // principal point (px)
  int mx = 0, my = 0;       // canvas margins (px) around the image for the distortion's resampling
  cv::Mat map_x, map_y;     // supersampled distorted pixel -> supersampled canvas pixel (distortion only)
  cv::Mat background;       // supersampled canvas
  bool distorted() const { return o.k1 != 0 || o.k2 != 0; }

  // K of the canvas at supersampling ss: canvas pixel (ss = 1) = image pixel + (mx, my);
  // supersampled pixel x2 = ss x + (ss - 1) / 2 (pixel centres; ss x ss blocks average to one pixel).
  cv::Matx33d Kc(int ss) const {
    const double cx = pp.x() + mx, cy = pp.y() + my;
    return cv::Matx33d(ss * o.focal_px, 0, ss * cx + 0.5 * (ss - 1), 0, ss * o.focal_px, ss * cy + 0.5 * (ss - 1), 0, 0, 1);
  }
  cv::Size canvasSize(int ss) const { return cv::Size(ss * (o.width + 2 * mx), ss * (o.height + 2 * my)); }

  struct Pose {
    Matrix3d R;  // camera -> world
    Vector3d C;
  };

  // The camera pose of motion time tau (moving body), with hand-held jitter interpolated between
  // moving frames.
  Pose poseAt(double t) const {
    const RenderOptions& p = o;
    const double sweep = p.sweepDeg();
    const double el_mid = 0.5 * (p.elevation0_deg + p.elevation1_deg) * kDegToRad;
    auto onSphere = [&](double az, double el, double r) {
      return Vector3d(centre + r * Vector3d(std::sin(az) * std::cos(el), std::sin(el), std::cos(az) * std::cos(el)));
    };
    const Vector3d C_mid = onSphere(az0_deg * kDegToRad, el_mid, r0);
    const Matrix3d R_mid = lookAt(C_mid, centre, 0);
    Pose out;
    switch (p.motion) {
      case MotionKind::Orbit: {
        const double u = t;
        const double az = (az0_deg + sweep * (u - 0.5) + 1.0 * std::sin(2 * M_PI * 1.3 * u + ph[0])) * kDegToRad;
        const double el = (p.elevation0_deg + (p.elevation1_deg - p.elevation0_deg) * u +
                           1.5 * std::sin(2 * M_PI * 0.8 * u + ph[1])) * kDegToRad;
        const double r = r0 * (1.0 + (p.approachRatio() - 1.0) * u) * (1.0 + 0.08 * std::sin(2 * M_PI * 0.6 * u + ph[2]));
        const double roll = (4.0 * std::sin(2 * M_PI * 0.7 * u + ph[3]) + 1.5 * std::sin(2 * M_PI * 1.9 * u + ph[4])) * kDegToRad;
        const Vector3d target =
            centre + 0.04 * Vector3d(std::sin(2 * M_PI * 1.1 * u + ph[5]), std::sin(2 * M_PI * 0.9 * u + ph[6]),
                                     std::sin(2 * M_PI * 1.7 * u + ph[7]));
        out.C = onSphere(az, el, r);
        out.R = lookAt(out.C, target, roll);
        break;
      }
      case MotionKind::Translate: {
        // Sideways along the camera's x axis; the whole baseline subtends `sweep` at the centre.
        const double s = 2 * r0 * std::tan(0.5 * sweep * kDegToRad) * (t - 0.5);
        out.R = R_mid;
        out.C = C_mid + R_mid.col(0) * s + R_mid.col(2) * (r0 - r0 * (1.0 + (p.approachRatio() - 1.0) * t));
        break;
      }
      case MotionKind::Rotate: {
        // Pan by `sweep` about the camera's y axis with a tilt arching up to 0.2 sweep, about the
        // centre of projection.
        const double yaw = sweep * (t - 0.5) * kDegToRad, pitch = 0.2 * sweep * std::sin(M_PI * t) * kDegToRad;
        out.C = C_mid;
        out.R = R_mid * Eigen::AngleAxisd(yaw, Vector3d::UnitY()).toRotationMatrix() *
                Eigen::AngleAxisd(pitch, Vector3d::UnitX()).toRotationMatrix();
        break;
      }
      case MotionKind::Forward: {
        out.R = R_mid;
        out.C = centre + (C_mid - centre) * (1.0 + (p.approachRatio() - 1.0) * t);
        break;
      }
      case MotionKind::None:
        out.R = R_mid;
        out.C = C_mid;
        break;
    }
    if (!jit_rot.empty()) {
      const int n = static_cast<int>(jit_rot.size());
      const double x = std::clamp(t, 0.0, 1.0) * (n - 1);
      const int j = std::min(static_cast<int>(std::floor(x)), n - 2);
      const double w = x - j;
      const Vector3d rot = (1 - w) * jit_rot[j] + w * jit_rot[j + 1];
      const Vector3d pos = (1 - w) * jit_pos[j] + w * jit_pos[j + 1];
      if (rot.norm() > 0) out.R = out.R * Eigen::AngleAxisd(rot.norm(), rot.normalized()).toRotationMatrix();
      out.C += pos;
    }
    return out;
  }

  // Rolling shutter (RenderOptions::readout): whether a frame's rows may be exposed at different
  // poses.
  bool rollingShutter() const { return o.readout > 0 && o.motion != MotionKind::None && o.frames > 1; }
  // The motion time at frame time kf (frames, fractional): the frames' motion times (tau)
  // interpolated, so flat over added still frames, and extrapolated before the first frame and
  // after the last with their neighbour's step (poseAt is analytic beyond [0, 1]).
  double motionTimeAt(double kf) const {
    const int k0 = std::clamp(static_cast<int>(std::floor(kf)), 0, o.frames - 2);
    return tau[k0] + (kf - k0) * (tau[k0 + 1] - tau[k0]);
  }
  // Motion time of image row y (px, the distorted image's rows) of frame k: frame time
  // k + readout (y - (H - 1)/2) / H.
  double rowTime(int k, double y) const {
    if (!rollingShutter()) return tau[k];
    return motionTimeAt(k + o.readout * (y - 0.5 * (o.height - 1)) / o.height);
  }
  // The moving body's camera pose when row y of frame k is exposed.
  Pose rowPose(int k, double y) const { return rollingShutter() ? poseAt(rowTime(k, y)) : Pose{Rwc[k], C[k]}; }
  // The largest image displacement (px, undistorted canvas) of a moving face's corner between
  // motion times t0 and t1.
  double maxDisplacement(double t0, double t1) const {
    const Pose a = poseAt(t0), b = poseAt(t1);
    double disp = 0;
    for (const Face& f : faces) {
      if (f.still) continue;
      const std::array<Vector3d, 4> poly{f.P0, f.P0 + f.Eu, f.P0 + f.Eu + f.Ev, f.P0 + f.Ev};
      const auto pa = project(poly, a, 1), pb = project(poly, b, 1);
      if (pa.size() != 4 || pb.size() != 4) continue;
      for (int i = 0; i < 4; ++i) disp = std::max(disp, std::hypot(pa[i].x - pb[i].x, pa[i].y - pb[i].y));
    }
    return disp;
  }
  // Bands of rows that frame k is rendered in, each at the pose of its middle row: 1 for a global
  // shutter, else enough that the image moves at most a quarter pixel from band to band (2 to 64:
  // a band's rows are at most 1/8 px from where their own time puts them; an eighth-pixel step
  // measured the same in BoxRender.ARollingShutterExposesEachRowAtItsOwnTime at twice the cost).
  int shutterBands(int k) const {
    if (!rollingShutter()) return 1;
    // Points on a 5 x 5 grid of every moving face, where they are in the image: a face's corners
    // can project far outside it (the floor's), and move far more than anything seen.
    const Pose a = poseAt(rowTime(k, 0)), b = poseAt(rowTime(k, o.height - 1));
    const Eigen::Vector2d lo(mx - 0.5, my - 0.5), hi(mx + o.width - 0.5, my + o.height - 0.5);
    auto pixel = [&](const Pose& cam, const Vector3d& X) -> std::optional<Eigen::Vector2d> {
      const Vector3d Xc = cam.R.transpose() * (X - cam.C);
      if (!(Xc.z() > 1e-9)) return std::nullopt;
      const cv::Matx33d Kk = Kc(1);
      return Eigen::Vector2d(Kk(0, 0) * Xc.x() / Xc.z() + Kk(0, 2), Kk(1, 1) * Xc.y() / Xc.z() + Kk(1, 2));
    };
    double disp = 0;
    for (const Face& f : faces) {
      if (f.still) continue;
      for (int i = 0; i <= 4; ++i)
        for (int j = 0; j <= 4; ++j) {
          const Vector3d X = f.P0 + 0.25 * i * f.Eu + 0.25 * j * f.Ev;
          const auto pa = pixel(a, X), pb = pixel(b, X);
          if (!pa || !pb) continue;
          const bool seen = (pa->array() >= lo.array()).all() && (pa->array() <= hi.array()).all();
          if (seen) disp = std::max(disp, (*pa - *pb).norm());
        }
    }
    if (!(disp > 1e-9)) return 1;  // nothing moves over the frame's rows (a still frame)
    return std::clamp(static_cast<int>(std::ceil(4 * disp)) + 1, 2, 64);
  }
  // Rows [y0, y1) of band b of `bands`.
  std::pair<int, int> bandRows(int b, int bands) const { return {b * o.height / bands, (b + 1) * o.height / bands}; }

  // Projected polygon (canvas pixels at supersampling ss) of a world polygon seen from `cam`.
  std::vector<cv::Point2d> project(const std::array<Vector3d, 4>& poly, const Pose& cam, int ss) const {
    std::vector<Vector3d> pc;
    for (const Vector3d& X : poly) pc.push_back(cam.R.transpose() * (X - cam.C));
    pc = clipNear(pc);
    std::vector<cv::Point2d> pts;
    const cv::Matx33d Kk = Kc(ss);
    for (const Vector3d& X : pc) {
      const cv::Vec3d x = Kk * cv::Vec3d(X.x(), X.y(), X.z());
      pts.emplace_back(x[0] / x[2], x[1] / x[2]);
    }
    return pts;
  }

  bool frontFacing(const Face& f, const Pose& cam) const { return f.n_out.dot(cam.C - f.P0) > 1e-9; }

  // Visible area (px) of a face in the (undistorted) image.
  double visibleArea(const Face& f, const Pose& cam) const {
    if (!frontFacing(f, cam)) return 0;
    const std::array<Vector3d, 4> poly{f.P0, f.P0 + f.Eu, f.P0 + f.Eu + f.Ev, f.P0 + f.Ev};
    const auto pts = project(poly, cam, 1);
    if (pts.size() < 3) return 0;
    std::vector<cv::Point2f> a, inter;
    for (const auto& q : pts) a.emplace_back(static_cast<float>(q.x - mx), static_cast<float>(q.y - my));
    const std::vector<cv::Point2f> img{{-0.5f, -0.5f}, {o.width - 0.5f, -0.5f}, {o.width - 0.5f, o.height - 0.5f},
                                       {-0.5f, o.height - 0.5f}};
    if (cv::contourArea(a, true) < 0) std::reverse(a.begin(), a.end());
    return cv::intersectConvexConvex(a, img, inter, true);
  }

  // Texture pixel (a, b) -> supersampled canvas pixel, for face f seen from `cam`, texture level 0.
  cv::Matx33d textureHomography(const Face& f, const Pose& cam) const {
    const cv::Mat& t = textures[f.texture].pyr[0];
    const Vector3d eu = f.Eu / (f.rep_u * t.cols), ev = f.Ev / (f.rep_v * t.rows);
    const Vector3d origin = f.P0 + 0.5 * eu + 0.5 * ev;
    const Matrix3d Rcw = cam.R.transpose();
    Matrix3d M;
    M.col(0) = Rcw * eu;
    M.col(1) = Rcw * ev;
    M.col(2) = Rcw * (origin - cam.C);
    return Kc(2) * toCv(M);
  }

  // Draws every face into the supersampled canvas `hi` seen from `cam` (moving body) and `still`
  // (still body).
  void drawFaces(cv::Mat& hi, const Pose& cam, const Pose& still) const;
  // Label image (canvas, ss = 1) of frame poses `cam`/`still`.
  void drawLabels(cv::Mat& labels, const Pose& cam, const Pose& still) const;
  // The label image (as Scene::labels) of the moving body seen from `cam`.
  cv::Mat labelsAt(const Pose& cam) const;

  void buildFaces(const std::function<void(const std::string&)>& say);
  void buildPath();
  void buildCanvas();
  void buildTruth();
};

void Scene::Impl::drawFaces(cv::Mat& hi, const Pose& cam, const Pose& still) const {
  const cv::Rect full(0, 0, hi.cols, hi.rows);
  for (const Face& f : faces) {
    const Pose& view = f.still ? still : cam;
    if (!frontFacing(f, view)) continue;
    for (const auto& cell : f.cells) {
      const auto pts = project(cell, view, 2);
      if (pts.size() < 3) continue;
      cv::Rect2d bb = cv::boundingRect(std::vector<cv::Point2f>(pts.begin(), pts.end()));
      cv::Rect roi(cv::Point(static_cast<int>(std::floor(bb.x)) - 1, static_cast<int>(std::floor(bb.y)) - 1),
                   cv::Point(static_cast<int>(std::ceil(bb.x + bb.width)) + 2,
                             static_cast<int>(std::ceil(bb.y + bb.height)) + 2));
      roi &= full;
      if (roi.area() == 0) continue;
      cv::Mat mask(roi.size(), CV_8U, cv::Scalar(0));
      std::vector<cv::Point2d> local;
      for (const auto& p : pts) local.emplace_back(p.x - roi.x, p.y - roi.y);
      fillConvexExact(mask, local, cv::Scalar(255));
      if (f.texture < 0) {
        hi(roi).setTo(f.flat * f.shade, mask);
        continue;
      }
      const cv::Matx33d H0 = textureHomography(f, view);
      const cv::Matx33d H0inv = H0.inv();
      const Texture& tex = textures[f.texture];
      // Texture level: texture pixels per output pixel at the visible cell's centre.
      cv::Point2d c(0, 0);
      for (const auto& p : pts) c += p;
      c *= 1.0 / pts.size();
      c.x = std::clamp(c.x, double(roi.x), double(roi.x + roi.width));
      c.y = std::clamp(c.y, double(roi.y), double(roi.y + roi.height));
      const cv::Vec3d ta = H0inv * cv::Vec3d(c.x, c.y, 1);
      const double au = ta[0] / ta[2], av = ta[1] / ta[2];
      const cv::Vec3d m = H0 * cv::Vec3d(au, av, 1);
      const double w = m[2];
      // Jacobian of the texture->image map at (au, av).
      const double j00 = (H0(0, 0) - m[0] / w * H0(2, 0)) / w, j01 = (H0(0, 1) - m[0] / w * H0(2, 1)) / w;
      const double j10 = (H0(1, 0) - m[1] / w * H0(2, 0)) / w, j11 = (H0(1, 1) - m[1] / w * H0(2, 1)) / w;
      const double texels_per_px = 1.0 / std::sqrt(std::max(1e-12, std::abs(j00 * j11 - j01 * j10)));
      int level = static_cast<int>(std::floor(std::log2(std::max(1.0, texels_per_px))));
      level = std::clamp(level, 0, static_cast<int>(tex.pyr.size()) - 1);
      const double sc = std::ldexp(1.0, level);
      const cv::Matx33d Hl = cv::Matx33d(1, 0, -roi.x, 0, 1, -roi.y, 0, 0, 1) * H0 *
                             cv::Matx33d(sc, 0, 0, 0, sc, 0, 0, 0, 1);  // pyrDown: level-L pixel i sits at 2^L i
      cv::Mat warped;
      cv::warpPerspective(tex.pyr[level], warped, Hl, roi.size(), cv::INTER_LINEAR, f.border);
      warped.convertTo(warped, CV_8UC3, f.shade);
      warped.copyTo(hi(roi), mask);
    }
  }
}

void Scene::Impl::drawLabels(cv::Mat& labels, const Pose& cam, const Pose& still) const {
  labels.create(canvasSize(1), CV_8U);
  labels.setTo(0);
  for (const Face& f : faces) {
    const Pose& view = f.still ? still : cam;
    if (!frontFacing(f, view)) continue;
    for (const auto& cell : f.cells) {
      const auto lp = project(cell, view, 1);
      if (lp.size() >= 3)
        fillConvexExact(labels, lp, cv::Scalar(f.still ? Scene::kStillLabel : f.truth_index >= 0 ? f.truth_index + 1 : 255));
    }
  }
}

void Scene::Impl::buildFaces(const std::function<void(const std::string&)>& say) {
  const double a = kBoxX, h = kBoxY, b = kBoxZ;
  auto face = [](std::string name, Vector3d P0, Vector3d Eu, Vector3d Ev) {
    Face f;
    f.plane = name;
    f.name = std::move(name);
    f.P0 = P0;
    f.Eu = Eu;
    f.Ev = Ev;
    f.n_out = Ev.cross(Eu).normalized();  // u right, v down seen from outside => n = v x u points out
    f.cells.push_back({P0, P0 + Eu, P0 + Eu + Ev, P0 + Ev});
    return f;
  };
  // Splits a face into an n x m grid of cells (each its own texture level).
  auto grid = [](Face& f, int nu, int nv) {
    f.cells.clear();
    const Vector3d du = f.Eu / nu, dv = f.Ev / nv;
    for (int i = 0; i < nu; ++i)
      for (int j = 0; j < nv; ++j) {
        const Vector3d c = f.P0 + i * du + j * dv;
        f.cells.push_back({c, c + du, c + du + dv, c + dv});
      }
  };
  auto tiled = [](Face& f) {
    f.border = cv::BORDER_REFLECT_101;
    f.rep_u = -1;  // set from the texture's aspect below (1 unit per tile)
  };
  const bool box_scene = o.scene == SceneKind::Box || o.scene == SceneKind::LowTexture;
  std::map<std::string, std::string> photo;  // face -> photograph (visp-images-data)
  const std::string floor_photo = "cube/image.0000.pgm";
  if (box_scene && o.floor) {
    Face f = face("floor", {-kFloorHalf, 0, -kFloorHalf}, {2 * kFloorHalf, 0, 0}, {0, 0, 2 * kFloorHalf});
    tiled(f);
    grid(f, kFloorCells, kFloorCells);
    faces.push_back(f);
    photo["floor"] = floor_photo;
  }
  if (o.scene == SceneKind::Object) {
    // The still wall behind the box: perpendicular to the first view's axis, centred on it, beyond
    // the box centre by 1.4 units, wide enough to fill the image (defined in buildPath's frame).
    Face f = face("wall", Vector3d::Zero(), Vector3d::UnitX(), Vector3d::UnitY());
    f.still = true;
    f.plane = "";  // not part of the truth: it does not move with the box
    tiled(f);
    faces.push_back(f);
    photo["wall"] = floor_photo;
  }
  if (box_scene || o.scene == SceneKind::Object) {
    faces.push_back(face("box_front", {-a / 2, h, b / 2}, {a, 0, 0}, {0, -h, 0}));
    faces.push_back(face("box_right", {a / 2, h, b / 2}, {0, 0, -b}, {0, -h, 0}));
    faces.push_back(face("box_top", {-a / 2, h, -b / 2}, {a, 0, 0}, {0, 0, b}));
    faces.push_back(face("box_left", {-a / 2, h, -b / 2}, {0, 0, b}, {0, -h, 0}));
    faces.push_back(face("box_back", {a / 2, h, -b / 2}, {-a, 0, 0}, {0, -h, 0}));
    photo["box_front"] = "Klimt/Klimt.png";
    photo["box_right"] = "Solvay/Solvay_conference_1927_Version2_1024x705.png";
    photo["box_top"] = "mire-2/image.0001.pgm";
    photo["box_left"] = "cube/image.0030.pgm";
    photo["box_back"] = "AprilTag/AprilTag.pgm";
  }
  if (o.scene == SceneKind::Corner) {
    Face fl = face("floor", {0, 0, 0}, {kRoom, 0, 0}, {0, 0, kRoom});
    // Seen from inside (x, y, z > 0) every face's outward normal points into the room.
    fl.n_out = Vector3d::UnitY();
    tiled(fl);
    grid(fl, 8, 8);
    Face wx = face("wall_x", {0, kRoomH, kRoom}, {0, 0, -kRoom}, {0, -kRoomH, 0});  // x = 0, facing +x
    wx.n_out = Vector3d::UnitX();
    tiled(wx);
    grid(wx, 8, 5);
    Face wz = face("wall_z", {0, kRoomH, 0}, {kRoom, 0, 0}, {0, -kRoomH, 0});  // z = 0, facing +z
    wz.n_out = Vector3d::UnitZ();
    tiled(wz);
    grid(wz, 8, 5);
    faces.push_back(fl);
    faces.push_back(wx);
    faces.push_back(wz);
    photo["floor"] = floor_photo;
    photo["wall_x"] = "Klimt/Klimt.png";
    photo["wall_z"] = "Solvay/Solvay_conference_1927_Version2_1024x705.png";
  }
  if (o.scene == SceneKind::Poster) {
    // A flat wall around the poster, then the poster on it (coplanar: one truth plane).
    Face wall = face("wall", {-3, 2.2, 0}, {6, 0, 0}, {0, -2.2, 0});
    wall.plane = "poster";
    wall.texture = -1;
    wall.flat = cv::Scalar(196, 200, 204);
    grid(wall, 4, 2);
    faces.push_back(wall);
    faces.push_back(face("poster", {-kPosterW / 2, kPosterY0 + kPosterH, 0}, {kPosterW, 0, 0}, {0, -kPosterH, 0}));
    photo["poster"] = "Klimt/Klimt.png";
  }
  const Vector3d light = Vector3d(0.35, 1.0, 0.55).normalized();
  for (Face& f : faces) f.shade = 0.5 + 0.5 * std::max(0.0, f.n_out.dot(light));

  // Low texture: every face flat-shaded in a plain colour, with a few small textured patches
  // (coplanar faces of the same truth plane, drawn after their face).
  std::vector<Face> patches;
  if (o.scene == SceneKind::LowTexture) {
    cv::RNG rng(o.seed * 4409 + 3);
    for (Face& f : faces) {
      f.flat = cv::Scalar(rng.uniform(120, 220), rng.uniform(120, 220), rng.uniform(120, 220));
      f.texture = -1;
      f.border = cv::BORDER_REPLICATE;
      const bool is_floor = f.name == "floor";
      const int count = is_floor ? 4 : 2;
      for (int i = 0; i < count; ++i) {
        // Floor patches near the box (within 1.5 units of its centre); face patches 25 % of the side.
        Face p = f;
        p.name = f.name + "_patch" + std::to_string(i);
        p.texture = 0;  // set below
        const double s = is_floor ? 0.12 : 0.25;
        const double u0 = is_floor ? rng.uniform(0.22, 0.66) : rng.uniform(0.05, 0.70);
        const double v0 = is_floor ? rng.uniform(0.22, 0.66) : rng.uniform(0.05, 0.70);
        p.P0 = f.P0 + u0 * f.Eu + v0 * f.Ev;
        p.Eu = s * f.Eu;
        p.Ev = s * f.Ev;
        p.cells = {{p.P0, p.P0 + p.Eu, p.P0 + p.Eu + p.Ev, p.P0 + p.Ev}};
        p.rep_u = p.rep_v = 1;
        patches.push_back(p);
      }
    }
  }

  // Textures: one per textured face (and patch).
  cv::Mat user;
  const bool procedural = o.texture == "procedural";
  if (!o.texture.empty() && !procedural) {
    user = cv::imread(o.texture, cv::IMREAD_COLOR);
    if (user.empty() || user.cols < 16 || user.rows < 16)
      throw std::runtime_error("--texture " + o.texture + ": cannot read an image of at least 16x16 pixels");
  }
  bool fallback_said = false;
  cv::RNG crop_rng(o.seed * 7919 + 17);
  auto assign = [&](Face& f, std::size_t i, const std::string& photo_path, bool whole) {
    const double aspect = f.Eu.norm() / f.Ev.norm();
    cv::Mat img;
    std::string source;
    if (!user.empty()) {
      const double fx = crop_rng.uniform(0.0, 1.0), fy = crop_rng.uniform(0.0, 1.0);
      img = whole ? user.clone() : cropToAspect(user, aspect, fx, fy, 0.7);
      source = fs::path(o.texture).filename().string() + (whole ? "" : " (crop)");
    } else {
      const std::string path = vispRoot() + photo_path;
      if (!procedural) img = cv::imread(path, cv::IMREAD_COLOR);
      if (!img.empty()) {
        // Drop a 5 % margin: some of the photographs have black borders, which would draw lines
        // on the tiled floor.
        const int mxp = img.cols / 20, myp = img.rows / 20;
        img = img(cv::Rect(mxp, myp, img.cols - 2 * mxp, img.rows - 2 * myp)).clone();
        if (!whole) img = cropToAspect(img, aspect, 0.5, 0.5, 1.0);
        source = path;
      } else {
        if (!fallback_said && !procedural)
          say(fmt::format("render: {} not found (install the Debian package visp-images-data for photographic "
                          "textures); using procedural textures",
                          path));
        fallback_said = true;
        img = proceduralTexture(o.seed * 31 + i, 512);
        if (!whole) img = cropToAspect(img, aspect, 0.5, 0.5, 1.0);
        source = fmt::format("procedural (seed {})", o.seed * 31 + i);
      }
    }
    if (f.rep_u < 0) {  // tiled: 1 unit per tile
      const double tile_w = 1.0, tile_h = tile_w * img.rows / img.cols;
      f.rep_u = f.Eu.norm() / tile_w;
      f.rep_v = f.Ev.norm() / tile_h;
    }
    f.texture = static_cast<int>(textures.size());
    textures.push_back(makeTexture(img, source));
  };
  for (std::size_t i = 0; i < faces.size(); ++i) {
    Face& f = faces[i];
    if (f.texture == -1 && (o.scene == SceneKind::LowTexture || (f.name == "wall" && o.scene == SceneKind::Poster))) continue;
    assign(f, i, photo.at(f.name), f.rep_u < 0);
  }
  if (!patches.empty()) {
    // Each patch: a crop of a photograph (the box faces' pictures in turn).
    const std::array<std::string, 5> pics{"Klimt/Klimt.png", "Solvay/Solvay_conference_1927_Version2_1024x705.png",
                                          "mire-2/image.0001.pgm", "cube/image.0030.pgm", "cube/image.0000.pgm"};
    for (std::size_t i = 0; i < patches.size(); ++i) assign(patches[i], faces.size() + i, pics[i % pics.size()], false);
    // Drawing order: each face, then its patches.
    std::vector<Face> ordered;
    for (const Face& f : faces) {
      ordered.push_back(f);
      for (const Face& p : patches)
        if (p.plane == f.plane) ordered.push_back(p);
    }
    faces = std::move(ordered);
  }
}

void Scene::Impl::buildPath() {
  // The rig: what the camera looks at, from which azimuth and how far.
  const double h = kBoxY;
  const double base_r = 1.95 * (o.focal_px / o.width) / (520.0 / 640.0);  // keeps the scene's image size
  switch (o.scene) {
    case SceneKind::Box:
    case SceneKind::LowTexture:
    case SceneKind::Object:
      centre = Vector3d(0, 0.45 * h, 0);
      az0_deg = 45;
      r0 = std::max(1.5, base_r);
      break;
    case SceneKind::Corner:
      centre = Vector3d(0.6, 0.75, 0.6);
      az0_deg = 45;
      r0 = std::max(1.5, 1.3 * base_r);
      break;
    case SceneKind::Poster:
      centre = Vector3d(0, kPosterY0 + 0.5 * kPosterH, 0);
      az0_deg = 20;
      r0 = std::max(1.5, base_r);
      break;
  }
  cv::RNG rng(o.seed * 1000003ULL + 7);
  for (double& p : ph) p = rng.uniform(0.0, 2 * M_PI);
  const int n = o.movingFrames();
  if (o.jitter_deg > 0) {
    cv::RNG jr(o.seed * 6364136223846793005ULL + 1442695040888963407ULL);
    const double s = o.jitter_deg * kDegToRad;
    for (int j = 0; j < n; ++j) {
      jit_rot.emplace_back(jr.gaussian(s), jr.gaussian(s), jr.gaussian(s));
      jit_pos.emplace_back(jr.gaussian(s * r0), jr.gaussian(s * r0), jr.gaussian(s * r0));
    }
  }
  // Frame -> moving index: still_start repeats of the first pose, then the first half of the
  // motion, still_middle repeats of its last pose, then the rest.
  const int S = o.still_start, M = o.still_middle, half = (n - 1) / 2;
  for (int k = 0; k < o.frames; ++k) {
    int m;
    bool added = false;
    if (k <= S) {
      m = 0;
      added = k > 0;
    } else if (k <= S + half) {
      m = k - S;
    } else if (k <= S + half + M) {
      m = half;
      added = true;
    } else {
      m = k - S - M;
    }
    const double t = n > 1 ? static_cast<double>(m) / (n - 1) : 0.0;
    tau.push_back(t);
    added_still.push_back(added);
    const Pose p = poseAt(t);
    Rwc.push_back(p.R);
    C.push_back(p.C);
  }
  // The object scene's still wall, fixed in the first camera's frame.
  for (Face& f : faces) {
    if (!f.still) continue;
    const double depth = (centre - C[0]).norm() + 1.4;
    const double hw = 1.3 * depth * (0.5 * o.width + std::abs(o.principal_offset_px.x())) / o.focal_px + 0.5;
    const double hh = 1.3 * depth * (0.5 * o.height + std::abs(o.principal_offset_px.y())) / o.focal_px + 0.5;
    const Matrix3d& R0 = Rwc[0];
    const Vector3d mid = C[0] + R0.col(2) * depth;
    f.P0 = mid - hw * R0.col(0) - hh * R0.col(1);
    f.Eu = 2 * hw * R0.col(0);
    f.Ev = 2 * hh * R0.col(1);
    f.n_out = -R0.col(2);
    f.rep_u = f.Eu.norm() / 1.0;
    const cv::Mat& t = textures[f.texture].pyr[0];
    f.rep_v = f.Ev.norm() / (1.0 * t.rows / t.cols);
    f.cells.clear();
    const int nu = 8, nv = 6;
    const Vector3d du = f.Eu / nu, dv = f.Ev / nv;
    for (int i = 0; i < nu; ++i)
      for (int j = 0; j < nv; ++j) {
        const Vector3d c = f.P0 + i * du + j * dv;
        f.cells.push_back({c, c + du, c + du + dv, c + dv});
      }
  }
}

void Scene::Impl::buildCanvas() {
  pp = Eigen::Vector2d(0.5 * (o.width - 1), 0.5 * (o.height - 1)) + o.principal_offset_px;
  if (distorted()) {
    // Undistorted positions of the image's border pixels: the canvas must cover them.
    auto undistortPx = [&](double x, double y) {
      const double xd = (x - pp.x()) / o.focal_px, yd = (y - pp.y()) / o.focal_px;
      const double rd = std::hypot(xd, yd);
      const double s = rd > 0 ? undistortRadius(rd, o.k1, o.k2) / rd : 1.0;
      return Eigen::Vector2d(pp.x() + o.focal_px * xd * s, pp.y() + o.focal_px * yd * s);
    };
    double xmin = 0, xmax = o.width - 1, ymin = 0, ymax = o.height - 1;
    for (int x = 0; x < o.width; ++x)
      for (int y : {0, o.height - 1}) {
        const auto u = undistortPx(x, y);
        xmin = std::min(xmin, u.x()), xmax = std::max(xmax, u.x()), ymin = std::min(ymin, u.y()), ymax = std::max(ymax, u.y());
      }
    for (int y = 0; y < o.height; ++y)
      for (int x : {0, o.width - 1}) {
        const auto u = undistortPx(x, y);
        xmin = std::min(xmin, u.x()), xmax = std::max(xmax, u.x()), ymin = std::min(ymin, u.y()), ymax = std::max(ymax, u.y());
      }
    mx = static_cast<int>(std::ceil(std::max(-xmin, xmax - (o.width - 1)))) + 3;
    my = static_cast<int>(std::ceil(std::max(-ymin, ymax - (o.height - 1)))) + 3;
    // Supersampled distorted pixel X2 (image pixel x = (X2 - 0.5) / 2) -> supersampled canvas pixel.
    map_x.create(2 * o.height, 2 * o.width, CV_32F);
    map_y.create(2 * o.height, 2 * o.width, CV_32F);
    for (int Y = 0; Y < 2 * o.height; ++Y)
      for (int X = 0; X < 2 * o.width; ++X) {
        const auto u = undistortPx(0.5 * (X - 0.5), 0.5 * (Y - 0.5));
        map_x.at<float>(Y, X) = static_cast<float>(2 * (u.x() + mx) + 0.5);
        map_y.at<float>(Y, X) = static_cast<float>(2 * (u.y() + my) + 0.5);
      }
  }
  // Background: a smooth vertical gradient (featureless).
  background.create(canvasSize(2), CV_8UC3);
  for (int y = 0; y < background.rows; ++y) {
    const double v = static_cast<double>(y) / background.rows;
    background.row(y).setTo(cv::Scalar(200 - 40 * v, 185 - 40 * v, 170 - 40 * v));
  }
}

void Scene::Impl::buildTruth() {
  // Truth: every plane of the moving body visible (front-facing, >= 0.2 % of the image) in at least
  // one frame, in face order.
  io::Summary& t = truth;
  t.frames = o.frames;
  t.width = o.width;
  t.height = o.height;
  t.principal_point_px = pp;
  t.focal_px = o.focal_px;
  if (distorted()) t.distortion = Eigen::Vector2d(o.k1, o.k2);
  switch (o.scene) {
    case SceneKind::Corner: t.scene_size = std::sqrt(3.0) * 1.5; break;  // the corner's 1.5-unit cube of interest
    case SceneKind::Poster: t.scene_size = std::hypot(kPosterW, kPosterH); break;
    default: t.scene_size = std::sqrt(kBoxX * kBoxX + kBoxY * kBoxY + kBoxZ * kBoxZ); break;
  }
  const Matrix3d R0 = Rwc[0];
  const Vector3d C0 = C[0];
  const Pose still{Rwc[0], C[0]};
  std::vector<std::string> planes;
  for (const Face& f : faces)
    if (!f.still && !f.plane.empty() && std::find(planes.begin(), planes.end(), f.plane) == planes.end())
      planes.push_back(f.plane);
  for (const std::string& name : planes) {
    int visible = 0;
    const Face* rep = nullptr;
    for (int k = 0; k < o.frames; ++k) {
      double area = 0;
      for (const Face& f : faces)
        if (f.plane == name && !f.still) {
          area = std::max(area, visibleArea(f, Pose{Rwc[k], C[k]}));
          if (!rep) rep = &f;
        }
      if (area >= 0.002 * o.width * o.height) ++visible;
    }
    if (visible == 0 || !rep) continue;
    Vector3d n = R0.transpose() * rep->n_out;
    double d = rep->n_out.dot(rep->P0) - rep->n_out.dot(C0);
    if (d < 0) {
      n = -n;
      d = -d;
    }
    const int index = static_cast<int>(t.planes.size());
    for (Face& f : faces)
      if (f.plane == name && !f.still) f.truth_index = index;
    t.planes.push_back(n);
    t.plane_distances.push_back(d);
    t.plane_names.push_back(name);
    t.plane_visible_frames.push_back(visible);
  }
  (void)still;
}

Scene::Scene(const RenderOptions& opt, const std::function<void(const std::string&)>& note)
    : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.o = opt;
  auto say = [&](const std::string& m) {
    if (note) note(m);
  };
  s.buildFaces(say);
  s.buildPath();
  s.buildCanvas();
  s.buildTruth();
}

Scene::~Scene() = default;

const RenderOptions& Scene::options() const { return impl_->o; }

int Scene::frames() const { return impl_->o.frames; }

double Scene::motionTime(int k) const { return impl_->tau.at(k); }

cv::Matx33d Scene::K() const {
  const Impl& s = *impl_;
  return cv::Matx33d(s.o.focal_px, 0, s.pp.x(), 0, s.o.focal_px, s.pp.y(), 0, 0, 1);
}

io::Summary Scene::truth() const { return impl_->truth; }

std::vector<Scene::FacePolygon> Scene::faces() const {
  const Impl& s = *impl_;
  std::vector<FacePolygon> r;
  for (const Face& f : s.faces) {
    FacePolygon p;
    p.name = f.name;
    p.truth_index = f.truth_index;
    p.still_body = f.still;
    p.textured = f.texture >= 0;
    const std::array<Vector3d, 4> w{f.P0, f.P0 + f.Eu, f.P0 + f.Eu + f.Ev, f.P0 + f.Ev};
    for (int i = 0; i < 4; ++i) p.corners[i] = s.Rwc[0].transpose() * (w[i] - s.C[0]);
    r.push_back(p);
  }
  return r;
}

std::vector<std::string> Scene::textureSources() const {
  std::vector<std::string> r;
  for (const Face& f : impl_->faces)
    r.push_back(f.name + ": " + (f.texture >= 0 ? impl_->textures[f.texture].source : std::string("flat")));
  return r;
}

io::TumPose Scene::pose(int k) const {
  const Impl& s = *impl_;
  io::TumPose p;
  p.t = k;
  p.p = s.Rwc[0].transpose() * (s.C[k] - s.C[0]);
  p.q = Eigen::Quaterniond(s.Rwc[0].transpose() * s.Rwc[k]).normalized();
  if (p.q.w() < 0) p.q.coeffs() = -p.q.coeffs();
  return p;
}

std::optional<Eigen::Vector2d> Scene::project(const Eigen::Vector3d& X_ref, int k, bool still_body) const {
  const Impl& s = *impl_;
  if (k < 0 || k >= s.o.frames) throw std::out_of_range("Scene::project: frame out of range");
  const Vector3d Xw = s.Rwc[0] * X_ref + s.C[0];
  auto through = [&](const Matrix3d& R, const Vector3d& Ck) -> std::optional<Eigen::Vector2d> {
    const Vector3d Xc = R.transpose() * (Xw - Ck);
    if (!(Xc.z() > 1e-9)) return std::nullopt;
    Eigen::Vector2d x = Xc.head<2>() / Xc.z();
    const double r2 = x.squaredNorm();
    x *= 1 + s.o.k1 * r2 + s.o.k2 * r2 * r2;
    return Eigen::Vector2d(s.o.focal_px * x.x() + s.pp.x(), s.o.focal_px * x.y() + s.pp.y());
  };
  if (still_body) return through(s.Rwc[0], s.C[0]);
  std::optional<Eigen::Vector2d> x = through(s.Rwc.at(k), s.C.at(k));
  if (!s.rollingShutter()) return x;
  // Rolling shutter: the row the point is seen in is exposed at that row's pose; a fixed point
  // (it contracts by the readout times the image's vertical motion per frame over its height).
  for (int it = 0; it < 20 && x; ++it) {
    const Impl::Pose p = s.rowPose(k, x->y());
    const std::optional<Eigen::Vector2d> next = through(p.R, p.C);
    if (!next) return std::nullopt;
    const bool settled = std::abs(next->y() - x->y()) < 1e-9;
    x = next;
    if (settled) break;
  }
  return x;
}

cv::Mat Scene::render(int k, cv::Mat* labels) const {
  const Impl& s = *impl_;
  if (k < 0 || k >= s.o.frames) throw std::out_of_range("Scene::render: frame out of range");
  const Impl::Pose still{s.Rwc[0], s.C[0]};
  const int n = s.o.movingFrames();
  // The supersampled canvas of the moving body at motion time t (pose `cam`), with its motion blur.
  auto canvasAt = [&](double t_mid, const Impl::Pose& cam) {
    cv::Mat hi;
    if (s.o.blur > 0 && !s.added_still[k] && s.o.motion != MotionKind::None) {
      // Motion blur: the mean of sub-frame renderings over the exposure [t - e, t + e], sampled
      // finely enough that the image moves at most one pixel between sub-frames.
      const double e = 0.5 * s.o.blur / (n - 1);
      const double t0 = std::max(0.0, t_mid - e), t1 = std::min(1.0, t_mid + e);
      const double disp = s.maxDisplacement(t0, t1);
      const int subs = std::clamp(static_cast<int>(std::ceil(disp)) + 1, 2, 48);
      cv::Mat acc(s.canvasSize(2), CV_32FC3, cv::Scalar::all(0));
      for (int i = 0; i < subs; ++i) {
        const double t = t0 + (t1 - t0) * i / (subs - 1);
        cv::Mat sub = s.background.clone();
        s.drawFaces(sub, s.poseAt(t), still);
        cv::accumulate(sub, acc);
      }
      acc.convertTo(hi, CV_8UC3, 1.0 / subs);
    } else {
      hi = s.background.clone();
      s.drawFaces(hi, cam, still);
    }
    return hi;
  };
  // The canvas resampled to the image (distortion, supersampling).
  auto toImage = [&](const cv::Mat& hi) {
    cv::Mat img;
    if (s.distorted()) {
      cv::Mat dist;
      cv::remap(hi, dist, s.map_x, s.map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      cv::resize(dist, img, cv::Size(s.o.width, s.o.height), 0, 0, cv::INTER_AREA);
    } else {
      cv::resize(hi, img, cv::Size(s.o.width, s.o.height), 0, 0, cv::INTER_AREA);
    }
    return img;
  };
  cv::Mat img;
  if (const int bands = s.shutterBands(k); bands == 1) {
    img = toImage(canvasAt(s.tau[k], Impl::Pose{s.Rwc[k], s.C[k]}));
  } else {
    // Rolling shutter: each band of rows from the frame rendered at its middle row's time.
    img.create(s.o.height, s.o.width, CV_8UC3);
    for (int b = 0; b < bands; ++b) {
      const auto [y0, y1] = s.bandRows(b, bands);
      const double t = s.rowTime(k, 0.5 * (y0 + y1 - 1));
      toImage(canvasAt(t, s.poseAt(t))).rowRange(y0, y1).copyTo(img.rowRange(y0, y1));
    }
  }
  if (labels) *labels = this->labels(k);
  if (s.o.noise_sigma > 0) {
    cv::RNG rng(s.o.seed * 1000003ULL + 7919ULL * static_cast<std::uint64_t>(k) + 1);
    cv::Mat noise(img.size(), CV_16SC3), img16;
    rng.fill(noise, cv::RNG::NORMAL, 0.0, s.o.noise_sigma);
    img.convertTo(img16, CV_16SC3);
    img16 += noise;
    img16.convertTo(img, CV_8UC3);
  }
  if (s.o.jpeg_quality > 0) {
    std::vector<uchar> buf;
    cv::imencode(".jpg", img, buf, {cv::IMWRITE_JPEG_QUALITY, s.o.jpeg_quality});
    img = cv::imdecode(buf, cv::IMREAD_COLOR);
  }
  return img;
}

std::optional<Eigen::Vector2d> Scene::transfer(const Eigen::Vector2d& x, int a, int b, const cv::Mat& labels_a) const {
  const Impl& s = *impl_;
  if (a < 0 || a >= s.o.frames || b < 0 || b >= s.o.frames) throw std::out_of_range("Scene::transfer: frame out of range");
  const int xi = static_cast<int>(std::lround(x.x())), yi = static_cast<int>(std::lround(x.y()));
  if (xi < 0 || yi < 0 || xi >= labels_a.cols || yi >= labels_a.rows) return std::nullopt;
  const int label = labels_a.at<uchar>(yi, xi);
  const Face* face = nullptr;
  for (const Face& f : s.faces)
    if ((label == kStillLabel && f.still) || (!f.still && f.truth_index >= 0 && f.truth_index + 1 == label)) {
      face = &f;
      break;
    }
  if (!face) return std::nullopt;
  const bool still = face->still;
  // The pose that exposed x's row (rolling shutter; the frame's pose for a global one).
  const Impl::Pose pa = still ? Impl::Pose{s.Rwc[0], s.C[0]} : s.rowPose(a, x.y());
  const Matrix3d& Ra = pa.R;
  const Vector3d& Ca = pa.C;
  // Undistort, cast the ray, meet the face's plane.
  const double xd = (x.x() - s.pp.x()) / s.o.focal_px, yd = (x.y() - s.pp.y()) / s.o.focal_px;
  const double rd = std::hypot(xd, yd);
  const double sc = rd > 0 && s.distorted() ? undistortRadius(rd, s.o.k1, s.o.k2) / rd : 1.0;
  const Vector3d dir = Ra * Vector3d(xd * sc, yd * sc, 1.0);
  const double den = face->n_out.dot(dir);
  if (std::abs(den) < 1e-12) return std::nullopt;
  const double lambda = face->n_out.dot(face->P0 - Ca) / den;
  if (!(lambda > 0)) return std::nullopt;
  const Vector3d Xw = Ca + lambda * dir;
  // The point in the reference camera frame of its body, projected into frame b.
  const Vector3d X_ref = s.Rwc[0].transpose() * (Xw - s.C[0]);
  return project(X_ref, b, still);
}

cv::Mat Scene::labels(int k) const {
  const Impl& s = *impl_;
  if (k < 0 || k >= s.o.frames) throw std::out_of_range("Scene::labels: frame out of range");
  const int bands = s.shutterBands(k);
  if (bands == 1) return s.labelsAt(Impl::Pose{s.Rwc[k], s.C[k]});
  // Rolling shutter: each band of rows at its middle row's pose, as render() draws it.
  cv::Mat out(s.o.height, s.o.width, CV_8U);
  for (int b = 0; b < bands; ++b) {
    const auto [y0, y1] = s.bandRows(b, bands);
    s.labelsAt(s.rowPose(k, 0.5 * (y0 + y1 - 1))).rowRange(y0, y1).copyTo(out.rowRange(y0, y1));
  }
  return out;
}

cv::Mat Scene::Impl::labelsAt(const Pose& cam) const {
  const Impl& s = *this;
  cv::Mat lc;
  s.drawLabels(lc, cam, Pose{s.Rwc[0], s.C[0]});
  if (!s.distorted()) return lc;
  // Distorted pixel x -> canvas pixel (ss = 1): the supersampled map's mean over the 2 x 2 block
  // of x (supersampled pixels 2x, 2x + 1), mapped back to ss = 1.
  cv::Mat mxs(s.o.height, s.o.width, CV_32F), mys(s.o.height, s.o.width, CV_32F);
  for (int y = 0; y < s.o.height; ++y)
    for (int x = 0; x < s.o.width; ++x) {
      const float X = 0.25f * (s.map_x.at<float>(2 * y, 2 * x) + s.map_x.at<float>(2 * y, 2 * x + 1) +
                               s.map_x.at<float>(2 * y + 1, 2 * x) + s.map_x.at<float>(2 * y + 1, 2 * x + 1));
      const float Y = 0.25f * (s.map_y.at<float>(2 * y, 2 * x) + s.map_y.at<float>(2 * y, 2 * x + 1) +
                               s.map_y.at<float>(2 * y + 1, 2 * x) + s.map_y.at<float>(2 * y + 1, 2 * x + 1));
      mxs.at<float>(y, x) = 0.5f * (X - 0.5f);
      mys.at<float>(y, x) = 0.5f * (Y - 0.5f);
    }
  cv::Mat out;
  cv::remap(lc, out, mxs, mys, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
  return out;
}

namespace {

int countFrames(const fs::path& file, cv::Mat* first) {
  cv::VideoCapture cap(file.string());
  if (!cap.isOpened()) return -1;
  int n = 0;
  cv::Mat f;
  while (cap.read(f)) {
    if (n == 0 && first) *first = f.clone();
    ++n;
  }
  return n;
}

}  // namespace

RenderResult writeSequence(const RenderOptions& o, const fs::path& out_dir, const std::function<void(int, int)>& progress,
                           const std::function<void(const std::string&)>& note, const std::string& extra_json) {
  const auto t0 = std::chrono::steady_clock::now();
  RenderResult res;
  auto say = [&](const std::string& m) {
    res.notes.push_back(m);
    if (note) note(m);
  };
  if (auto msg = validate(o); !msg.empty()) throw std::invalid_argument(msg);
  Scene scene(o, say);
  const fs::path truth_dir = out_dir / "truth";
  std::error_code ec;
  const bool made_truth_dir = !fs::exists(truth_dir, ec);
  fs::create_directories(truth_dir, ec);
  if (ec) throw std::runtime_error("cannot create " + truth_dir.string() + ": " + ec.message());
  struct Cleanup {
    fs::path dir;
    bool active;
    ~Cleanup() {
      std::error_code e;
      if (active && fs::is_empty(dir, e)) fs::remove(dir, e);
    }
  } cleanup{truth_dir, made_truth_dir};

  // Pick the container: a 2-frame probe must be writable and read back.
  const cv::Size size(o.width, o.height);
  auto files = std::make_unique<io::AtomicFileSet>();
  fs::path video_final = out_dir / "video.mp4";
  int fourcc = cv::VideoWriter::fourcc('m', 'p', '4', 'v');
  {
    io::AtomicFileSet probe;
    const fs::path p = probe.temp(out_dir / "probe.mp4");
    bool ok = false;
    {
      cv::VideoWriter w(p.string(), cv::CAP_FFMPEG, fourcc, o.fps, size, true);
      if (w.isOpened()) {
        const cv::Mat blank(size, CV_8UC3, cv::Scalar(128, 128, 128));
        w.write(blank);
        w.write(blank);
        w.release();
        ok = countFrames(p, nullptr) == 2;
      }
    }
    probe.abort();
    if (!ok) {
      say("render: this OpenCV cannot write and read back mp4 (mp4v); writing MJPG video.avi instead");
      res.mp4 = false;
      video_final = out_dir / "video.avi";
      fourcc = cv::VideoWriter::fourcc('M', 'J', 'P', 'G');
    }
  }
  const fs::path video_tmp = files->temp(video_final);
  cv::Mat first_rendered;
  {
    cv::VideoWriter w;
    if (res.mp4)
      w.open(video_tmp.string(), cv::CAP_FFMPEG, fourcc, o.fps, size, true);
    else
      w.open(video_tmp.string(), fourcc, o.fps, size, true);
    if (!w.isOpened()) throw std::runtime_error("cannot open a video writer for " + video_final.string());
    for (int k = 0; k < o.frames; ++k) {
      const cv::Mat img = scene.render(k);
      if (k == 0) first_rendered = img;
      w.write(img);
      if (progress) progress(k + 1, o.frames);
    }
    w.release();
  }
  cv::Mat first_read;
  const int n = countFrames(video_tmp, &first_read);
  if (n != o.frames)
    throw std::runtime_error(fmt::format("{} reads back with {} frames instead of {}", video_final.string(), n, o.frames));
  if (!first_read.empty() && first_read.size() == first_rendered.size()) {
    cv::Mat ga, gb;
    cv::cvtColor(first_read, ga, cv::COLOR_BGR2GRAY);
    cv::cvtColor(first_rendered, gb, cv::COLOR_BGR2GRAY);
    say(fmt::format("render: video reads back with {} frames; frame 0 PSNR against the rendered image {:.1f} dB "
                    "(BGR), {:.1f} dB (grey)",
                    n, cv::PSNR(first_read, first_rendered), cv::PSNR(ga, gb)));
  }
  std::vector<io::TumPose> poses;
  for (int k = 0; k < o.frames; ++k) {
    poses.push_back(scene.pose(k));
    poses.back().t = k / o.fps;  // seconds at the video's frame rate, as `rsfm run` writes them
  }
  std::ostringstream tum;
  io::writeTum(tum, poses);
  io::Summary truth = scene.truth();
  truth.fps = o.fps;
  const Determinacy det = analyseDeterminacy(scene);
  truth.determinable = det.summary;
  nlohmann::ordered_json rj;
  rj["format"] = "rsfm-render";
  rj["version"] = 1;
  rj["options"] = nlohmann::ordered_json::parse(optionsToJson(o));
  rj["moving_frames"] = o.movingFrames();
  rj["sweep_deg"] = o.sweepDeg();
  rj["determinacy"] = nlohmann::ordered_json::parse(determinacyToJson(det));
  rj["textures"] = scene.textureSources();
  if (!extra_json.empty()) {
    const auto extra = nlohmann::ordered_json::parse(extra_json);
    for (auto it = extra.begin(); it != extra.end(); ++it) rj[it.key()] = it.value();
  }
  files->write(truth_dir / "trajectory.tum", tum.str());
  files->write(truth_dir / "summary.json", io::summaryToJson(truth));
  files->write(truth_dir / "render.json", rj.dump(2) + "\n");
  files->write(truth_dir / "camera.yaml",
               io::cameraYaml(o.width, o.height, o.focal_px, truth.principal_point_px.x(), truth.principal_point_px.y(), o.k1,
                              o.k2, {"source: \"rsfm render (the truth)\""}));
  files->commit();
  cleanup.active = false;
  res.video = video_final;
  res.frames = n;
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace rsfm::render
