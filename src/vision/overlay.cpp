#include "rsfm/vision/overlay.hpp"

#include <fmt/format.h>

#include <algorithm>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <stdexcept>

#include "rsfm/camera.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/vision/frame_source.hpp"

namespace rsfm::vision {

namespace {

const cv::Scalar kColours[] = {{255, 160, 0}, {0, 200, 0}, {255, 0, 200}, {0, 200, 255}, {200, 200, 0}};

cv::Scalar colourOf(int label) {
  if (label == -1) return {0, 0, 255};
  if (label < 0) return {160, 160, 160};
  return kColours[label % 5];
}

/// Grid nodes of plane j: a 9x9 grid over the bounding box of the plane's tracks in the reference
/// frame, back-projected onto the plane (reference frame, A&P coordinates, [AS99] eq. 12) with the
/// final estimate: its reference-frame tracks, or for a plane with fewer than 3 there (one that
/// came into view later) all its tracks, each carried back from its first frame through the plane
/// and that frame's pose (PlaneModel::transferToReference).
std::vector<std::vector<Eigen::Vector3d>> planeGrid(const Tracks& tracks, const std::vector<int>& labels, int j,
                                                    const TrackFilterResult& result, double s) {
  const TrackFrame& fin = result.frames.back();
  // The grid spans the 5th to 95th percentiles of the plane's tracks, so that a few stray
  // members do not stretch it.
  std::vector<double> xs, ys;
  std::vector<char> seen(labels.size(), 0);
  // The reference frame's tracks; a plane with too few there (one that came into view later):
  // every track of it, from its first frame.
  const int frames = std::min(tracks.numFrames(), static_cast<int>(result.frames.size()));
  int with_reference = 0;
  for (const auto& p : tracks.frames[0]) with_reference += p.id < static_cast<int>(labels.size()) && labels[p.id] == j;
  for (int k = 0; k < (with_reference >= 3 ? 1 : frames); ++k)
    for (const auto& p : tracks.frames[static_cast<size_t>(k)]) {
      if (p.id >= static_cast<int>(labels.size()) || labels[p.id] != j || seen[p.id]) continue;
      seen[p.id] = 1;
      const Eigen::Vector2d uv((p.px.x() - tracks.image.cx) / s, (p.px.y() - tracks.image.cy) / s);
      Eigen::Vector2d ref = uv;
      const TrackFrame& f = result.frames[static_cast<size_t>(k)];
      if (k > 0 && PlaneModel::transferToReference(fin.N[j], f.beta, f.R, f.t, uv, &ref) != MeasureStatus::Ok) continue;
      xs.push_back(ref.x());
      ys.push_back(ref.y());
    }
  const int n = static_cast<int>(xs.size());
  if (n < 3) return {};
  std::sort(xs.begin(), xs.end());
  std::sort(ys.begin(), ys.end());
  const double x0 = xs[n / 20], x1 = xs[n - 1 - n / 20], y0 = ys[n / 20], y1 = ys[n - 1 - n / 20];
  std::vector<std::vector<Eigen::Vector3d>> g;
  const int G = 9;
  g.assign(G, std::vector<Eigen::Vector3d>(G, Eigen::Vector3d::Constant(std::nan(""))));
  for (int a = 0; a < G; ++a)
    for (int b = 0; b < G; ++b) {
      const Eigen::Vector2d uv(x0 + (x1 - x0) * b / (G - 1), y0 + (y1 - y0) * a / (G - 1));
      Eigen::Vector3d X;
      if (PlaneModel::point(fin.N[j], fin.beta, uv, &X, nullptr, nullptr) == MeasureStatus::Ok) g[a][b] = X;
    }
  return g;
}

/// The video's frame size: H.264 and MPEG-4 in 4:2:0 need an even width and height (OpenCV's
/// writer would otherwise drop the last column or row), so an odd side gets one more pixel.
cv::Size evenSize(cv::Size s) { return {s.width + s.width % 2, s.height + s.height % 2}; }

/// Writes one frame, padded with black on the right / bottom to evenSize().
void writeFrame(cv::VideoWriter* vw, const cv::Mat& bgr) {
  if (bgr.cols % 2 == 0 && bgr.rows % 2 == 0) {
    vw->write(bgr);
    return;
  }
  cv::Mat padded;
  cv::copyMakeBorder(bgr, padded, 0, bgr.rows % 2, 0, bgr.cols % 2, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  vw->write(padded);
}

/// Opens `vw` for H.264 in MP4 (fourcc avc1, FFmpeg's libx264: playable in browsers), else
/// MPEG-4 Part 2 (mp4v) with a warning in `info` (FFmpeg without an H.264 encoder).
void openWriter(cv::VideoWriter* vw, const std::filesystem::path& path, double fps, cv::Size size, OverlayInfo* info) {
  if (vw->open(path.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('a', 'v', 'c', '1'), fps, size)) {
    info->codec = "h264";
    return;
  }
  if (vw->open(path.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('m', 'p', '4', 'v'), fps, size)) {
    info->codec = "mpeg4";
    info->warning = fmt::format("overlay.mp4 is MPEG-4 Part 2, which browsers do not play: no H.264 encoder for {}x{} "
                                "frames (FFmpeg's libx264 missing?)",
                                size.width, size.height);
    return;
  }
  throw std::runtime_error(fmt::format("{}: cannot open a video writer (H.264 or MPEG-4)", path.string()));
}

/// The poster: one frame (the middle one) of the overlay as PNG bytes.
void keepPoster(const cv::Mat& bgr, size_t fi, size_t frames, OverlayInfo* info) {
  if (fi != frames / 2) return;
  cv::Mat small = bgr;
  if (bgr.cols > 960) cv::resize(bgr, small, cv::Size(960, bgr.rows * 960 / bgr.cols), 0, 0, cv::INTER_AREA);
  cv::imencode(".png", small, info->poster_png);
}

}  // namespace

OverlayInfo writeOverlay(const std::string& input, FrameRange range, const Tracks& tracks, const std::vector<int>& labels,
                  const TrackFilterResult& result, const std::filesystem::path& path) {
  FrameSource src(input);
  const double s = result.scale_px;
  const TrackFrame& fin = result.frames.back();
  std::vector<std::vector<std::vector<Eigen::Vector3d>>> grids;
  for (int j = 0; j < static_cast<int>(fin.N.size()); ++j) grids.push_back(planeGrid(tracks, labels, j, result, s));
  cv::VideoWriter vw;
  OverlayInfo info;
  cv::Mat img, bgr;
  size_t fi = 0;
  // The tracks start at range.first, or later when its first frames had none (a fade-in:
  // trimLeadingEmptyFrames), and so does the result.
  const int first = std::max(range.first, tracks.first_frame);
  while (src.read(&img) && fi < result.frames.size()) {
    if (src.index() < first) continue;
    const int k = src.index() - first;  // index within tracks.frames
    if (img.channels() == 1) cv::cvtColor(img, bgr, cv::COLOR_GRAY2BGR);
    else bgr = img.clone();
    if (!vw.isOpened()) openWriter(&vw, path, src.fps(), evenSize(bgr.size()), &info);
    const TrackFrame& tf = result.frames[fi];
    // Plane grids with this frame's motion: u = X_C / (1 + beta Z_C), X_C = t + R X.
    for (size_t j = 0; j < grids.size(); ++j) {
      const auto& g = grids[j];
      if (g.empty()) continue;
      // A plane that came into view later is drawn from the frame it joined the filter.
      if (!result.planeEstimatedAt(static_cast<int>(j), static_cast<int>(fi))) continue;
      auto proj = [&](const Eigen::Vector3d& X, cv::Point2f* q) {
        if (!X.allFinite()) return false;
        const Eigen::Vector3d Xc = tf.t + tf.R * X;
        const double w = 1.0 + tf.beta * Xc.z();
        if (!(w > 1e-6)) return false;
        *q = cv::Point2f(static_cast<float>(Xc.x() / w * s + tracks.image.cx),
                         static_cast<float>(Xc.y() / w * s + tracks.image.cy));
        return std::abs(q->x) < 1e5 && std::abs(q->y) < 1e5;
      };
      const cv::Scalar c = colourOf(static_cast<int>(j));
      for (size_t a = 0; a < g.size(); ++a)
        for (size_t b = 0; b < g[a].size(); ++b) {
          cv::Point2f p, q;
          if (!proj(g[a][b], &p)) continue;
          if (b + 1 < g[a].size() && proj(g[a][b + 1], &q)) cv::line(bgr, p, q, c, 1, cv::LINE_AA);
          if (a + 1 < g.size() && proj(g[a + 1][b], &q)) cv::line(bgr, p, q, c, 1, cv::LINE_AA);
        }
    }
    if (k < tracks.numFrames())
      for (const auto& p : tracks.frames[k]) {
        const int l = p.id < static_cast<int>(labels.size()) ? labels[p.id] : -2;
        const cv::Point2f q(static_cast<float>(p.px.x()), static_cast<float>(p.px.y()));
        if (l == -1) {
          cv::drawMarker(bgr, q, colourOf(l), cv::MARKER_CROSS, 7, 1, cv::LINE_AA);
        } else {
          cv::circle(bgr, q, 3, colourOf(l), l >= 0 ? -1 : 1, cv::LINE_AA);
        }
      }
    cv::putText(bgr, fmt::format("frame {}  f = {:.0f} px", tf.frame, s / tf.beta), {10, 22}, cv::FONT_HERSHEY_SIMPLEX,
                0.6, {255, 255, 255}, 2, cv::LINE_AA);
    cv::putText(bgr, fmt::format("frame {}  f = {:.0f} px", tf.frame, s / tf.beta), {10, 22}, cv::FONT_HERSHEY_SIMPLEX,
                0.6, {0, 0, 0}, 1, cv::LINE_AA);
    writeFrame(&vw, bgr);
    keepPoster(bgr, fi, result.frames.size(), &info);
    ++fi;
  }
  if (fi == 0) throw std::runtime_error(input + ": no frame to draw the overlay on");
  return info;
}

OverlayInfo writePatchOverlay(const std::string& input, FrameRange range, const PatchTracks& tracks, const PatchRunResult& result,
                       const std::filesystem::path& path) {
  FrameSource src(input);
  const double s = result.scale_px;
  cv::VideoWriter vw;
  OverlayInfo info;
  cv::Mat img, bgr;
  size_t fi = 0;
  const Eigen::Vector2d cpx(tracks.image.cx, tracks.image.cy);
  const int first = std::max(range.first, tracks.first_frame);  // as writeOverlay's
  while (src.read(&img) && fi < result.frames.size()) {
    if (src.index() < first) continue;
    const int k = src.index() - first;
    if (img.channels() == 1) cv::cvtColor(img, bgr, cv::COLOR_GRAY2BGR);
    else bgr = img.clone();
    if (!vw.isOpened()) openWriter(&vw, path, src.fps(), evenSize(bgr.size()), &info);
    const PatchRunFrame& f = result.frames[fi];
    const NormalAgreement agree = normalAgreement(f);
    for (size_t i = 0; i < f.patches.size(); ++i) {
      const PatchEstimate& e = f.patches[i];
      const PatchObservation* ob = tracks.find(k, e.id);
      const bool good = agree.angle_deg[i] <= 5.0;
      const cv::Scalar colour = good ? cv::Scalar(0, 220, 0) : cv::Scalar(0, 140, 255);
      if (ob) {  // the warped square
        const double r = tracks.radius;
        std::vector<cv::Point> sq;
        for (const Eigen::Vector2d& q : {Eigen::Vector2d(-r, -r), Eigen::Vector2d(r, -r), Eigen::Vector2d(r, r), Eigen::Vector2d(-r, r)}) {
          const Eigen::Vector2d p = ob->A * q + ob->px;
          sq.emplace_back(cvRound(p.x()), cvRound(p.y()));
        }
        cv::polylines(bgr, std::vector<std::vector<cv::Point>>{sq}, true, {200, 200, 200}, 1, cv::LINE_AA);
      }
      // The normal: from the centre's 3-D point (A&P) a segment of depth / 5 towards the camera.
      const Eigen::Vector2d uv = (e.px - cpx) / s;
      const double Z = e.depth, w0 = 1.0 + f.beta * Z;
      if (!(w0 > 0)) continue;
      const Eigen::Vector3d X(uv.x() * w0, uv.y() * w0, Z);
      const Eigen::Vector3d Y = X - 0.05 * std::abs(Z + 1.0 / f.beta) * e.normal;
      const double w1 = 1.0 + f.beta * Y.z();
      if (!(w1 > 1e-6)) continue;
      Eigen::Vector2d tip = Y.head<2>() / w1 * s + cpx;
      if (!tip.allFinite()) continue;
      // Keep the arrow readable: at most 2.5 patch radii long in the image (its direction is
      // what matters).
      const double len = (tip - e.px).norm(), cap = 2.5 * std::max(5, tracks.radius);
      if (len > cap) tip = e.px + (tip - e.px) * (cap / len);
      const cv::Point2f a(static_cast<float>(e.px.x()), static_cast<float>(e.px.y()));
      cv::arrowedLine(bgr, a, cv::Point2f(static_cast<float>(tip.x()), static_cast<float>(tip.y())), colour, 2, cv::LINE_AA, 0,
                      0.25);
      cv::circle(bgr, a, 2, colour, -1, cv::LINE_AA);
    }
    const std::string text = fmt::format("frame {}  f {:.0f} px  {}/{} within 5 deg", f.frame, s / f.beta,
                                         agree.within_5deg, f.patches.size());
    cv::putText(bgr, text, {10, 22}, cv::FONT_HERSHEY_SIMPLEX, 0.5, {255, 255, 255}, 2, cv::LINE_AA);
    cv::putText(bgr, text, {10, 22}, cv::FONT_HERSHEY_SIMPLEX, 0.5, {0, 0, 0}, 1, cv::LINE_AA);
    writeFrame(&vw, bgr);
    keepPoster(bgr, fi, result.frames.size(), &info);
    ++fi;
  }
  if (fi == 0) throw std::runtime_error(input + ": no frame to draw the overlay on");
  return info;
}

}  // namespace rsfm::vision
