// Synthetic patch scenes ([Cal00]; docs/patches.md). See patch_scene.hpp.
#include "rsfm/sim/patch_scene.hpp"
#include "rsfm/units.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "rsfm/rotation.hpp"

namespace rsfm {

namespace {

constexpr double kHalfWidth = 0.5;  // sphere scene image half-width (f = 1, 53 degree field of view)

Eigen::Vector2d project(const Eigen::Vector3d& X, double beta) { return X.head<2>() / (1.0 + beta * X.z()); }

/// COP (A&P coordinates) and the direction of the ray through image point c: X = o + l d.
void ray(const Eigen::Vector2d& c, double beta, Eigen::Vector3d* o, Eigen::Vector3d* d) {
  *o = Eigen::Vector3d(0, 0, -1.0 / beta);
  *d = Eigen::Vector3d(c.x(), c.y(), 1.0 / beta);
}

/// Offsets (normalized image units) of a cluster: two rings of points around the centre.
std::vector<Eigen::Vector2d> clusterOffsets(int n, double diameter_deg, double beta) {
  const double r = std::tan(0.5 * diameter_deg * kDegToRad) / beta;
  std::vector<Eigen::Vector2d> out;
  for (int j = 0; j < n; ++j) {
    const double a = 2.0 * 3.14159265358979323846 * j / n + (j % 2 ? 0.3 : 0.0);
    const double rr = j % 2 ? 0.5 * r : r;
    out.emplace_back(rr * std::cos(a), rr * std::sin(a));
  }
  return out;
}

struct Cluster {
  Eigen::Vector3d centre;             // frame-0 3-D centre point
  Eigen::Vector3d normal;             // frame-0 unit surface normal at the centre (towards the camera)
  std::vector<Eigen::Vector3d> pts;   // frame-0 3-D cluster points (centre excluded)
};

/// True when every point of the cluster projects inside the image (|u|, |v| <= half_width) and
/// the surface faces the camera, no more obliquely than max_obliquity_deg, in every frame.
bool clusterVisible(const Cluster& c, const std::vector<Eigen::Matrix3d>& R, const std::vector<Eigen::Vector3d>& t,
                    double beta, double half_width, double max_obliquity_deg) {
  const Eigen::Vector3d cop(0, 0, -1.0 / beta);
  for (size_t k = 0; k < R.size(); ++k) {
    const Eigen::Vector3d Xc = R[k] * c.centre + t[k], n = R[k] * c.normal;
    if (!(1.0 + beta * Xc.z() > 0.0) || !(n.dot((cop - Xc).normalized()) > std::cos(max_obliquity_deg * kDegToRad))) return false;
    if (project(Xc, beta).cwiseAbs().maxCoeff() > half_width) return false;
    for (const Eigen::Vector3d& X : c.pts) {
      const Eigen::Vector3d Y = R[k] * X + t[k];
      if (!(1.0 + beta * Y.z() > 0.0) || project(Y, beta).cwiseAbs().maxCoeff() > half_width) return false;
    }
  }
  return true;
}

/// Builds everything from the clusters and the per-frame poses.
PatchScene build(const std::vector<Cluster>& clusters, const std::vector<Eigen::Matrix3d>& R,
                 const std::vector<Eigen::Vector3d>& t, double beta, double half_width, const char* what) {
  PatchScene s;
  s.beta = beta;
  s.R = R;
  s.t = t;
  const int F = static_cast<int>(R.size()) - 1, K = static_cast<int>(clusters.size());
  s.centre.assign(F + 1, std::vector<Eigen::Vector2d>(K));
  s.affine.assign(F + 1, std::vector<Vector6d>(K, Vector6d::Zero()));
  s.structure.assign(F + 1, std::vector<Eigen::Vector3d>(K));
  s.normal.assign(F + 1, std::vector<Eigen::Vector3d>(K));
  s.motion.assign(F + 1, Eigen::Matrix<double, 7, 1>::Zero());
  s.motion[0][6] = beta;
  for (const Cluster& c : clusters) s.centre_points0.push_back(c.centre);
  std::vector<std::vector<Eigen::Vector2d>> prev(K);
  for (int k = 0; k <= F; ++k) {
    if (k > 0) {
      const Eigen::Matrix3d Rr = R[k] * R[k - 1].transpose();
      const Eigen::Vector3d tr = t[k] - Rr * t[k - 1];
      Eigen::Quaterniond q(Rr);
      q = canonical(q);
      s.motion[k] << tr.x(), tr.y(), tr.z() * beta, 2.0 * q.x(), 2.0 * q.y(), 2.0 * q.z(), beta;
    }
    for (int p = 0; p < K; ++p) {
      const Cluster& c = clusters[p];
      const Eigen::Vector3d Xc = R[k] * c.centre + t[k];
      const Eigen::Vector3d n = R[k] * c.normal;
      if (!(1.0 + beta * Xc.z() > 0.0)) throw std::runtime_error(std::string(what) + ": a patch went behind the camera");
      // The surface must face the camera: the COP is on the normal's side.
      const Eigen::Vector3d cop(0, 0, -1.0 / beta);
      if (!(n.dot(cop - Xc) > 0.0)) throw std::runtime_error(std::string(what) + ": a patch turned away from the camera");
      s.centre[k][p] = project(Xc, beta);
      if (s.centre[k][p].cwiseAbs().maxCoeff() > half_width)
        throw std::runtime_error(std::string(what) + ": a patch left the image");
      // The model's orientation: the normal points away from the camera (sigma > 0).
      if (!PatchModel::structureFromPlane(-n, -n.dot(Xc), beta, &s.structure[k][p]))
        throw std::runtime_error(std::string(what) + ": a patch plane is not visible");
      s.normal[k][p] = -n;
      std::vector<Eigen::Vector2d> img;
      for (const Eigen::Vector3d& X : c.pts) img.push_back(project(R[k] * X + t[k], beta));
      if (k > 0) {
        // Least squares: img_k = h + A (img_{k-1} - centre_{k-1}).
        const int m = static_cast<int>(img.size());
        Eigen::MatrixXd M(m + 1, 3);
        Eigen::MatrixXd B(m + 1, 2);
        M.row(0) << 1.0, 0.0, 0.0;  // the centre point itself
        B.row(0) = s.centre[k][p].transpose();
        for (int j = 0; j < m; ++j) {
          const Eigen::Vector2d d = prev[p][j] - s.centre[k - 1][p];
          M.row(j + 1) << 1.0, d.x(), d.y();
          B.row(j + 1) = img[j].transpose();
        }
        const Eigen::MatrixXd sol = M.colPivHouseholderQr().solve(B);  // 3 x 2
        s.affine[k][p] << sol(0, 0), sol(0, 1), sol(1, 0), sol(2, 0), sol(1, 1), sol(2, 1);
      }
      prev[p] = img;
    }
  }
  return s;
}

}  // namespace

PatchScene makeSphereScene(const SphereSceneOptions& o, std::mt19937_64& rng) {
  if (o.frames < 1 || o.patches < 1 || o.cluster_points < 3 || !(o.radius > 0.0) || !(o.beta > 0.0) ||
      !(o.max_obliquity_deg > 0.0 && o.max_obliquity_deg <= 90.0))
    throw std::runtime_error("sphere scene: bad options");
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const Eigen::Vector3d cop(0, 0, -1.0 / o.beta);
  const Eigen::Vector3d towards = (cop - o.centre).normalized();
  // Orthonormal basis around the direction facing the camera.
  const Eigen::Vector3d e1 = towards.unitOrthogonal(), e2 = towards.cross(e1);
  std::vector<Eigen::Matrix3d> R(o.frames + 1);
  std::vector<Eigen::Vector3d> t(o.frames + 1);
  auto turn = [&](int k) {
    const double ph = 2.0 * 3.14159265358979323846 * k / o.frames;
    return (Eigen::AngleAxisd(o.angle_x_deg * kDegToRad * std::sin(ph), Eigen::Vector3d::UnitX()) *
            Eigen::AngleAxisd(o.angle_y_deg * kDegToRad * std::sin(ph + 1.0), Eigen::Vector3d::UnitY()))
        .toRotationMatrix();
  };
  const Eigen::Matrix3d Q0 = turn(0);
  for (int k = 0; k <= o.frames; ++k) {
    const double ph = 2.0 * 3.14159265358979323846 * k / o.frames;
    const Eigen::Vector3d Ck = o.centre + Eigen::Vector3d(o.amplitude.x() * std::sin(ph), o.amplitude.y() * std::sin(ph + 1.0),
                                                          o.amplitude.z() * (1.0 - std::cos(ph)));
    // X_k = C_k + Q_k Q_0^T (X_0 - C_0): the sphere turned about its centre relative to frame 0.
    R[k] = turn(k) * Q0.transpose();
    t[k] = Ck - R[k] * o.centre;
  }
  std::vector<Cluster> clusters;
  const std::vector<Eigen::Vector2d> offsets = clusterOffsets(o.cluster_points, o.cluster_deg, o.beta);
  const double min_sep = o.min_separation_deg;
  for (int tries = 0; static_cast<int>(clusters.size()) < o.patches; ++tries) {
    if (tries > 100000) throw std::runtime_error("sphere scene: cannot place the clusters");
    const double ct = 1.0 - uni(rng) * (1.0 - std::cos(o.max_off_axis_deg * kDegToRad));
    const double st = std::sqrt(std::max(0.0, 1.0 - ct * ct)), ph = 2.0 * 3.14159265358979323846 * uni(rng);
    const Eigen::Vector3d nrm = ct * towards + st * (std::cos(ph) * e1 + std::sin(ph) * e2);
    bool far = true;
    for (const Cluster& c : clusters)
      if (std::acos(std::clamp(c.normal.dot(nrm), -1.0, 1.0)) < min_sep * kDegToRad) far = false;
    if (!far) continue;
    Cluster c;
    c.centre = o.centre + o.radius * nrm;
    c.normal = nrm;
    const Eigen::Vector2d ci = project(c.centre, o.beta);
    bool ok = true;
    for (const Eigen::Vector2d& d : offsets) {
      Eigen::Vector3d org, dir;
      ray(ci + d, o.beta, &org, &dir);
      // |org + l dir - C|^2 = r^2, nearest root.
      const Eigen::Vector3d oc = org - o.centre;
      const double a = dir.squaredNorm(), b = 2.0 * dir.dot(oc), cc = oc.squaredNorm() - o.radius * o.radius;
      const double disc = b * b - 4.0 * a * cc;
      if (!(disc > 0.0)) {
        ok = false;
        break;
      }
      c.pts.push_back(org + dir * ((-b - std::sqrt(disc)) / (2.0 * a)));
    }
    // Re-drawn unless the whole cluster stays in the image and faces the camera in every frame.
    if (ok && clusterVisible(c, R, t, o.beta, kHalfWidth, o.max_obliquity_deg)) clusters.push_back(c);
  }
  PatchScene s = build(clusters, R, t, o.beta, kHalfWidth, "sphere scene");
  s.scale_px = 256.0 / 0.5;  // a 512-pixel image over the half-width 0.5
  return s;
}

PatchScene makePlanePatchScene(const PlanePatchSceneOptions& o, std::mt19937_64& rng) {
  Table1SceneOptions to = o.table1;
  to.points = o.patches;
  const Table1Scene t1 = makeTable1Scene(to, rng);
  const double beta = to.beta;
  const Eigen::Vector3d n0 = to.plane.normalized();
  const double d0 = 1.0 / to.plane.norm();
  std::vector<Cluster> clusters;
  const std::vector<Eigen::Vector2d> offsets = clusterOffsets(o.cluster_points, o.cluster_deg, beta);
  for (const Eigen::Vector3d& X : t1.points) {
    Cluster c;
    c.centre = X;
    c.normal = n0;
    const Eigen::Vector2d ci = project(X, beta);
    for (const Eigen::Vector2d& d : offsets) {
      Eigen::Vector3d org, dir;
      ray(ci + d, beta, &org, &dir);
      c.pts.push_back(org + dir * ((d0 - n0.dot(org)) / n0.dot(dir)));
    }
    clusters.push_back(c);
  }
  // The normal must point towards the camera (sigma > 0).
  for (Cluster& c : clusters)
    if (c.normal.dot(Eigen::Vector3d(0, 0, -1.0 / beta) - c.centre) < 0) c.normal = -c.normal;
  std::vector<Eigen::Matrix3d> R(t1.R.begin(), t1.R.end());
  std::vector<Eigen::Vector3d> t(t1.t.begin(), t1.t.end());
  const double half = to.image_px / (2.0 * to.scale_px);
  PatchScene s = build(clusters, R, t, beta, half, "plane patch scene");
  s.scale_px = to.scale_px;
  s.plane_normal0 = clusters.empty() ? n0 : clusters[0].normal;
  return s;
}

Vector6d relativeNoiseSd(const PatchScene& scene, double rho) {
  Vector6d mx = Vector6d::Zero();
  for (int k = 1; k <= scene.frames(); ++k)
    for (int p = 0; p < scene.patches(); ++p) {
      Vector6d f = scene.affine[k][p];
      f.head<2>() -= scene.centre[k - 1][p];
      f[2] -= 1.0;
      f[5] -= 1.0;
      mx = mx.cwiseMax(f.cwiseAbs());
    }
  // The centre's two coordinates share one scale, the four entries of A another: a parameter that
  // never moves in a scene (A_12 under a rotation about y) would otherwise get a zero deviation.
  const double mh = mx.head<2>().maxCoeff(), ma = mx.tail<4>().maxCoeff();
  Vector6d sd;
  sd << mh, mh, ma, ma, ma, ma;
  return rho * sd;
}

}  // namespace rsfm
