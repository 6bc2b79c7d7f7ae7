#include "rsfm/render/box_render.hpp"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <stdexcept>

#include "rsfm/io/atomic_file.hpp"

namespace rsfm::render {
namespace fs = std::filesystem;
using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

constexpr double kDeg = M_PI / 180.0;
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

struct Texture {
  std::vector<cv::Mat> pyr;  // level 0 = full resolution, BGR 8-bit
  std::string source;
};

struct Face {
  std::string name;
  Vector3d P0, Eu, Ev, n_out;  // corner, edges (texture u right, v down), outward normal
  double rep_u = 1, rep_v = 1;  // texture repetitions along Eu, Ev
  int texture = 0;
  int border = cv::BORDER_REPLICATE;
  double shade = 1;
  int truth_index = -1;
  std::vector<std::array<Vector3d, 4>> cells;  // polygons to draw (one, or the floor's grid)
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

}  // namespace

std::string validate(const BoxRenderOptions& o) {
  if (o.frames < 2 || o.frames > 100000) return fmt::format("--frames must be in [2, 100000], got {}", o.frames);
  if (o.width < 64 || o.height < 48 || o.width > 8192 || o.height > 8192)
    return fmt::format("--width/--height must be in [64, 8192] x [48, 8192], got {}x{}", o.width, o.height);
  if (o.width % 2 || o.height % 2) return fmt::format("--width and --height must be even (video), got {}x{}", o.width, o.height);
  if (!std::isfinite(o.focal_px) || o.focal_px < 0.3 * o.width || o.focal_px > 10.0 * o.width)
    return fmt::format("--focal-px must be in [0.3, 10] x width = [{}, {}], got {}", 0.3 * o.width, 10.0 * o.width,
                       o.focal_px);
  if (!std::isfinite(o.noise_sigma) || o.noise_sigma < 0 || o.noise_sigma > 50)
    return fmt::format("--noise must be in [0, 50] grey levels, got {}", o.noise_sigma);
  if (!std::isfinite(o.orbit_deg) || o.orbit_deg < 0 || o.orbit_deg > 80)
    return fmt::format("--orbit-deg must be in [0, 80], got {}", o.orbit_deg);
  for (double e : {o.elevation0_deg, o.elevation1_deg})
    if (!std::isfinite(e) || e < 5 || e > 85) return fmt::format("--elevation values must be in [5, 85] deg, got {}", e);
  if (!std::isfinite(o.approach) || o.approach < 0.3 || o.approach > 3)
    return fmt::format("--approach must be in [0.3, 3], got {}", o.approach);
  if (!std::isfinite(o.fps) || o.fps <= 0 || o.fps > 240) return fmt::format("--fps must be in (0, 240], got {}", o.fps);
  if (!o.texture.empty() && o.texture != "procedural") {
    std::error_code ec;
    if (!fs::is_regular_file(o.texture, ec)) return "--texture " + o.texture + ": no such file";
    const cv::Mat img = cv::imread(o.texture, cv::IMREAD_COLOR);
    if (img.empty() || img.cols < 16 || img.rows < 16)
      return "--texture " + o.texture + ": not an image OpenCV can read, or smaller than 16x16 pixels";
  }
  return {};
}

struct BoxScene::Impl {
  BoxRenderOptions o;
  std::vector<Texture> textures;
  std::vector<Face> faces;  // painter's order: floor first
  std::vector<Matrix3d> Rwc;  // camera -> world
  std::vector<Vector3d> C;    // camera centres (world)
  io::Summary truth;
  cv::Mat background;         // supersampled

  cv::Matx33d K(int ss) const {
    // ss = 2: supersampled pixel x2 = 2 x + 0.5 (pixel centres; 2x2 blocks average to one pixel).
    const double cx = 0.5 * (o.width - 1), cy = 0.5 * (o.height - 1);
    return cv::Matx33d(ss * o.focal_px, 0, ss * cx + 0.5 * (ss - 1), 0, ss * o.focal_px, ss * cy + 0.5 * (ss - 1), 0,
                       0, 1);
  }

  // Projected polygon (pixels at supersampling ss) of a world polygon seen from camera k.
  std::vector<cv::Point2d> project(const std::array<Vector3d, 4>& poly, int k, int ss) const {
    std::vector<Vector3d> cam;
    for (const Vector3d& X : poly) cam.push_back(Rwc[k].transpose() * (X - C[k]));
    cam = clipNear(cam);
    std::vector<cv::Point2d> pts;
    const cv::Matx33d Kk = K(ss);
    for (const Vector3d& X : cam) {
      const cv::Vec3d x = Kk * cv::Vec3d(X.x(), X.y(), X.z());
      pts.emplace_back(x[0] / x[2], x[1] / x[2]);
    }
    return pts;
  }

  bool frontFacing(const Face& f, int k) const { return f.n_out.dot(C[k] - f.P0) > 1e-9; }

  double visibleArea(const Face& f, int k) const {
    if (!frontFacing(f, k)) return 0;
    const std::array<Vector3d, 4> poly{f.P0, f.P0 + f.Eu, f.P0 + f.Eu + f.Ev, f.P0 + f.Ev};
    const auto pts = project(poly, k, 1);
    if (pts.size() < 3) return 0;
    std::vector<cv::Point2f> a(pts.begin(), pts.end()), inter;
    const std::vector<cv::Point2f> img{{-0.5f, -0.5f}, {o.width - 0.5f, -0.5f}, {o.width - 0.5f, o.height - 0.5f},
                                       {-0.5f, o.height - 0.5f}};
    if (cv::contourArea(a, true) < 0) std::reverse(a.begin(), a.end());
    return cv::intersectConvexConvex(a, img, inter, true);
  }

  // Texture pixel (a, b) -> supersampled image pixel, for face f, camera k, texture level 0.
  cv::Matx33d textureHomography(const Face& f, int k) const {
    const cv::Mat& t = textures[f.texture].pyr[0];
    const Vector3d eu = f.Eu / (f.rep_u * t.cols), ev = f.Ev / (f.rep_v * t.rows);
    const Vector3d origin = f.P0 + 0.5 * eu + 0.5 * ev;
    const Matrix3d Rcw = Rwc[k].transpose();
    Matrix3d M;
    M.col(0) = Rcw * eu;
    M.col(1) = Rcw * ev;
    M.col(2) = Rcw * (origin - C[k]);
    return K(2) * toCv(M);
  }
};

BoxScene::BoxScene(const BoxRenderOptions& opt, const std::function<void(const std::string&)>& note)
    : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.o = opt;
  auto say = [&](const std::string& m) {
    if (note) note(m);
  };
  const double a = kBoxX, h = kBoxY, b = kBoxZ;
  // Faces in the truth's fixed order.
  auto face = [](std::string name, Vector3d P0, Vector3d Eu, Vector3d Ev) {
    Face f;
    f.name = std::move(name);
    f.P0 = P0;
    f.Eu = Eu;
    f.Ev = Ev;
    f.n_out = Ev.cross(Eu).normalized();  // u right, v down seen from outside => n = v x u points out
    f.cells.push_back({P0, P0 + Eu, P0 + Eu + Ev, P0 + Ev});
    return f;
  };
  if (opt.floor) {
    Face f = face("floor", {-kFloorHalf, 0, -kFloorHalf}, {2 * kFloorHalf, 0, 0}, {0, 0, 2 * kFloorHalf});
    f.border = cv::BORDER_REFLECT_101;
    f.cells.clear();
    const Vector3d du = f.Eu / kFloorCells, dv = f.Ev / kFloorCells;
    for (int i = 0; i < kFloorCells; ++i)
      for (int j = 0; j < kFloorCells; ++j) {
        const Vector3d c = f.P0 + i * du + j * dv;
        f.cells.push_back({c, c + du, c + du + dv, c + dv});
      }
    s.faces.push_back(f);
  }
  s.faces.push_back(face("box_front", {-a / 2, h, b / 2}, {a, 0, 0}, {0, -h, 0}));
  s.faces.push_back(face("box_right", {a / 2, h, b / 2}, {0, 0, -b}, {0, -h, 0}));
  s.faces.push_back(face("box_top", {-a / 2, h, -b / 2}, {a, 0, 0}, {0, 0, b}));
  s.faces.push_back(face("box_left", {-a / 2, h, -b / 2}, {0, 0, b}, {0, -h, 0}));
  s.faces.push_back(face("box_back", {a / 2, h, -b / 2}, {-a, 0, 0}, {0, -h, 0}));
  const Vector3d light = Vector3d(0.35, 1.0, 0.55).normalized();
  for (Face& f : s.faces) f.shade = 0.5 + 0.5 * std::max(0.0, f.n_out.dot(light));

  // Textures: one per face.
  const std::map<std::string, std::string> defaults = {
      {"floor", "cube/image.0000.pgm"},
      {"box_front", "Klimt/Klimt.png"},
      {"box_right", "Solvay/Solvay_conference_1927_Version2_1024x705.png"},
      {"box_top", "mire-2/image.0001.pgm"},
      {"box_left", "cube/image.0030.pgm"},
      {"box_back", "AprilTag/AprilTag.pgm"}};
  cv::Mat user;
  const bool procedural = opt.texture == "procedural";
  if (!opt.texture.empty() && !procedural) {
    user = cv::imread(opt.texture, cv::IMREAD_COLOR);
    if (user.empty() || user.cols < 16 || user.rows < 16)
      throw std::runtime_error("--texture " + opt.texture + ": cannot read an image of at least 16x16 pixels");
  }
  bool fallback_said = false;
  cv::RNG crop_rng(opt.seed * 7919 + 17);
  for (std::size_t i = 0; i < s.faces.size(); ++i) {
    Face& f = s.faces[i];
    const bool is_floor = f.name == "floor";
    const double aspect = f.Eu.norm() / f.Ev.norm();
    cv::Mat img;
    std::string source;
    if (!user.empty()) {
      const double fx = crop_rng.uniform(0.0, 1.0), fy = crop_rng.uniform(0.0, 1.0);
      img = is_floor ? user.clone() : cropToAspect(user, aspect, fx, fy, 0.7);
      source = fs::path(opt.texture).filename().string() + (is_floor ? "" : " (crop)");
    } else {
      const std::string path = vispRoot() + defaults.at(f.name);
      if (!procedural) img = cv::imread(path, cv::IMREAD_COLOR);
      if (!img.empty()) {
        // Drop a 5 % margin: some of the photographs have black borders, which would draw lines
        // on the tiled floor.
        const int mx = img.cols / 20, my = img.rows / 20;
        img = img(cv::Rect(mx, my, img.cols - 2 * mx, img.rows - 2 * my)).clone();
        if (!is_floor) img = cropToAspect(img, aspect, 0.5, 0.5, 1.0);
        source = path;
      } else {
        if (!fallback_said && !procedural)
          say(fmt::format("render: {} not found (install the Debian package visp-images-data for photographic "
                          "textures); using procedural textures",
                          path));
        fallback_said = true;
        img = proceduralTexture(opt.seed * 31 + i, 512);
        if (!is_floor) img = cropToAspect(img, aspect, 0.5, 0.5, 1.0);
        source = fmt::format("procedural (seed {})", opt.seed * 31 + i);
      }
    }
    if (is_floor) {
      const double tile_w = 1.0, tile_h = tile_w * img.rows / img.cols;
      f.rep_u = f.Eu.norm() / tile_w;
      f.rep_v = f.Ev.norm() / tile_h;
    }
    f.texture = static_cast<int>(s.textures.size());
    s.textures.push_back(makeTexture(img, source));
  }

  // Camera path: a hand-held-like orbit about the box (docs/render.md).
  cv::RNG rng(opt.seed * 1000003ULL + 7);
  double ph[8];
  for (double& p : ph) p = rng.uniform(0.0, 2 * M_PI);
  const double r0 = std::max(1.5, 1.95 * (opt.focal_px / opt.width) / (520.0 / 640.0));
  const Vector3d centre(0, 0.45 * h, 0);
  for (int k = 0; k < opt.frames; ++k) {
    const double u = opt.frames > 1 ? static_cast<double>(k) / (opt.frames - 1) : 0.0;
    const double az = (45.0 + opt.orbit_deg * (u - 0.5) + 1.0 * std::sin(2 * M_PI * 1.3 * u + ph[0])) * kDeg;
    const double el =
        (opt.elevation0_deg + (opt.elevation1_deg - opt.elevation0_deg) * u + 1.5 * std::sin(2 * M_PI * 0.8 * u + ph[1])) * kDeg;
    const double r = r0 * (1.0 + (opt.approach - 1.0) * u) * (1.0 + 0.08 * std::sin(2 * M_PI * 0.6 * u + ph[2]));
    const double roll = (4.0 * std::sin(2 * M_PI * 0.7 * u + ph[3]) + 1.5 * std::sin(2 * M_PI * 1.9 * u + ph[4])) * kDeg;
    const Vector3d target =
        centre + 0.04 * Vector3d(std::sin(2 * M_PI * 1.1 * u + ph[5]), std::sin(2 * M_PI * 0.9 * u + ph[6]),
                                 std::sin(2 * M_PI * 1.7 * u + ph[7]));
    const Vector3d Ck = centre + r * Vector3d(std::sin(az) * std::cos(el), std::sin(el), std::cos(az) * std::cos(el));
    const Vector3d z = (target - Ck).normalized();
    const Vector3d x = z.cross(Vector3d::UnitY()).normalized();
    const Vector3d y = z.cross(x);
    Matrix3d R;
    R.col(0) = std::cos(roll) * x + std::sin(roll) * y;
    R.col(1) = -std::sin(roll) * x + std::cos(roll) * y;
    R.col(2) = z;
    s.Rwc.push_back(R);
    s.C.push_back(Ck);
  }

  // Truth: every face visible (front-facing, >= 0.2 % of the image) in at least one frame.
  io::Summary& t = s.truth;
  t.frames = opt.frames;
  t.width = opt.width;
  t.height = opt.height;
  t.principal_point_px = {0.5 * (opt.width - 1), 0.5 * (opt.height - 1)};
  t.focal_px = opt.focal_px;
  t.scene_size = std::sqrt(a * a + h * h + b * b);
  const Matrix3d R0 = s.Rwc[0];
  const Vector3d C0 = s.C[0];
  for (Face& f : s.faces) {
    int visible = 0;
    for (int k = 0; k < opt.frames; ++k)
      if (s.visibleArea(f, k) >= 0.002 * opt.width * opt.height) ++visible;
    if (visible == 0) continue;
    Vector3d n = R0.transpose() * f.n_out;
    double d = f.n_out.dot(f.P0) - f.n_out.dot(C0);
    if (d < 0) {
      n = -n;
      d = -d;
    }
    f.truth_index = static_cast<int>(t.planes.size());
    t.planes.push_back(n);
    t.plane_distances.push_back(d);
    t.plane_names.push_back(f.name);
    t.plane_visible_frames.push_back(visible);
  }

  // Background: a smooth vertical gradient (featureless).
  s.background.create(2 * opt.height, 2 * opt.width, CV_8UC3);
  for (int y = 0; y < s.background.rows; ++y) {
    const double v = static_cast<double>(y) / s.background.rows;
    s.background.row(y).setTo(cv::Scalar(200 - 40 * v, 185 - 40 * v, 170 - 40 * v));
  }
}

BoxScene::~BoxScene() = default;

int BoxScene::frames() const { return impl_->o.frames; }

cv::Matx33d BoxScene::K() const { return impl_->K(1); }

io::Summary BoxScene::truth() const { return impl_->truth; }

std::vector<BoxScene::FacePolygon> BoxScene::faces() const {
  const Impl& s = *impl_;
  std::vector<FacePolygon> r;
  for (const Face& f : s.faces) {
    FacePolygon p;
    p.name = f.name;
    p.truth_index = f.truth_index;
    const std::array<Vector3d, 4> w{f.P0, f.P0 + f.Eu, f.P0 + f.Eu + f.Ev, f.P0 + f.Ev};
    for (int i = 0; i < 4; ++i) p.corners[i] = s.Rwc[0].transpose() * (w[i] - s.C[0]);
    r.push_back(p);
  }
  return r;
}

std::vector<std::string> BoxScene::textureSources() const {
  std::vector<std::string> r;
  for (const Face& f : impl_->faces) r.push_back(f.name + ": " + impl_->textures[f.texture].source);
  return r;
}

io::TumPose BoxScene::pose(int k) const {
  const Impl& s = *impl_;
  io::TumPose p;
  p.t = k;
  p.p = s.Rwc[0].transpose() * (s.C[k] - s.C[0]);
  p.q = Eigen::Quaterniond(s.Rwc[0].transpose() * s.Rwc[k]).normalized();
  if (p.q.w() < 0) p.q.coeffs() = -p.q.coeffs();
  return p;
}

cv::Mat BoxScene::render(int k, cv::Mat* labels) const {
  const Impl& s = *impl_;
  if (k < 0 || k >= s.o.frames) throw std::out_of_range("BoxScene::render: frame out of range");
  cv::Mat hi = s.background.clone();
  const cv::Rect full(0, 0, hi.cols, hi.rows);
  if (labels) {
    labels->create(s.o.height, s.o.width, CV_8U);
    labels->setTo(0);
  }
  for (const Face& f : s.faces) {
    if (!s.frontFacing(f, k)) continue;
    const cv::Matx33d H0 = s.textureHomography(f, k);
    const cv::Matx33d H0inv = H0.inv();
    const Texture& tex = s.textures[f.texture];
    for (const auto& cell : f.cells) {
      const auto pts = s.project(cell, k, 2);
      if (pts.size() < 3) continue;
      cv::Rect2d bb = cv::boundingRect(std::vector<cv::Point2f>(pts.begin(), pts.end()));
      cv::Rect roi(cv::Point(static_cast<int>(std::floor(bb.x)) - 1, static_cast<int>(std::floor(bb.y)) - 1),
                   cv::Point(static_cast<int>(std::ceil(bb.x + bb.width)) + 2,
                             static_cast<int>(std::ceil(bb.y + bb.height)) + 2));
      roi &= full;
      if (roi.area() == 0) continue;
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
      cv::Mat mask(roi.size(), CV_8U, cv::Scalar(0));
      std::vector<cv::Point2d> local;
      for (const auto& p : pts) local.emplace_back(p.x - roi.x, p.y - roi.y);
      fillConvexExact(mask, local, cv::Scalar(255));
      warped.convertTo(warped, CV_8UC3, f.shade);
      warped.copyTo(hi(roi), mask);
      if (labels) {
        const auto lp = s.project(cell, k, 1);
        if (lp.size() >= 3)
          fillConvexExact(*labels, lp, cv::Scalar(f.truth_index >= 0 ? f.truth_index + 1 : 255));
      }
    }
  }
  cv::Mat img;
  cv::resize(hi, img, cv::Size(s.o.width, s.o.height), 0, 0, cv::INTER_AREA);
  if (s.o.noise_sigma > 0) {
    cv::RNG rng(s.o.seed * 1000003ULL + 7919ULL * static_cast<std::uint64_t>(k) + 1);
    cv::Mat noise(img.size(), CV_16SC3), img16;
    rng.fill(noise, cv::RNG::NORMAL, 0.0, s.o.noise_sigma);
    img.convertTo(img16, CV_16SC3);
    img16 += noise;
    img16.convertTo(img, CV_8UC3);
  }
  return img;
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

RenderResult writeBoxSequence(const BoxRenderOptions& o, const fs::path& out_dir,
                              const std::function<void(int, int)>& progress,
                              const std::function<void(const std::string&)>& note) {
  const auto t0 = std::chrono::steady_clock::now();
  RenderResult res;
  auto say = [&](const std::string& m) {
    res.notes.push_back(m);
    if (note) note(m);
  };
  if (auto msg = validate(o); !msg.empty()) throw std::invalid_argument(msg);
  BoxScene scene(o, say);
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
  for (int k = 0; k < o.frames; ++k) poses.push_back(scene.pose(k));
  std::ostringstream tum;
  io::writeTum(tum, poses);
  files->write(truth_dir / "trajectory.tum", tum.str());
  files->write(truth_dir / "summary.json", io::summaryToJson(scene.truth()));
  files->commit();
  cleanup.active = false;
  res.video = video_final;
  res.frames = n;
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace rsfm::render
