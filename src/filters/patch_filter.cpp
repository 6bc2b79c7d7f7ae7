// Calway's affine-patch filter ([Cal00]; docs/patches.md). See patch_filter.hpp.
#include "rsfm/filters/patch_filter.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "rsfm/rotation.hpp"

namespace rsfm {

std::string_view toString(PatchCentres c) {
  switch (c) {
    case PatchCentres::Measured: return "measured";
    case PatchCentres::Predicted: return "predicted";
    case PatchCentres::Fused: return "fused";
    case PatchCentres::State: return "state";
  }
  return "?";
}

bool parsePatchCentres(std::string_view s, PatchCentres* out) {
  if (s == "measured") *out = PatchCentres::Measured;
  else if (s == "predicted") *out = PatchCentres::Predicted;
  else if (s == "fused") *out = PatchCentres::Fused;
  else if (s == "state") *out = PatchCentres::State;
  else return false;
  return true;
}

PatchFilter::PatchFilter(PatchModel model, Ekf ekf, int gauge, PatchFilterOptions options)
    : model_(std::move(model)), ekf_(std::move(ekf)), gauge_(gauge), opt_(options) {
  if (ekf_.size() != model_.stateDim()) throw std::invalid_argument("patch filter: state size does not match the patches");
  if (gauge < 0 || gauge >= model_.numPatches()) throw std::invalid_argument("patch filter: gauge patch out of range");
  opt_.update.min_blocks = std::max(opt_.update.min_blocks, PatchModel::kMinPatches);
  ekf_.setFixed(PatchModel::p4Index(gauge_), true);
  gauge_value_ = ekf_.x()[PatchModel::p4Index(gauge_)];
  centre_cov_.assign(model_.numPatches(), Eigen::Matrix2d::Identity() * opt_.centre_sd * opt_.centre_sd);
  if (mapsInState()) {
    if (opt_.measurement != AffineMeasurement::Exact)
      throw std::invalid_argument("patch filter: maps in the state (centres 'state') need the exact measurement");
    const int K = model_.numPatches();
    Eigen::VectorXd w(6 * K);
    for (int k = 0; k < K; ++k) w.segment<6>(6 * k) << model_.centre(k), 1.0, 0.0, 0.0, 1.0;
    Eigen::MatrixXd Pw = Eigen::MatrixXd::Zero(6 * K, 6 * K);
    for (int k = 0; k < K; ++k) Pw.block<6, 6>(6 * k, 6 * k) = initialMapCovariance();
    ekf_.augment(w, Pw, Eigen::MatrixXd::Zero(6 * K, ekf_.size()));
  }
}

Eigen::Matrix<double, 6, 6> PatchFilter::initialMapCovariance() const {
  // Exact by definition (the template frame's map is (c, I)); a variance of 1e-6 of the
  // measurement's keeps P non-singular (the maps are otherwise functions of the other states,
  // and a singular P fails the update's factorization).
  return (1e-6 * opt_.measurement_sd.array().square()).matrix().asDiagonal();
}

double PatchFilter::regaugeState(int gauge, double value, Eigen::VectorXd* y, Eigen::MatrixXd* G) const {
  // The maps are image quantities: a rescaling of the scene leaves them unchanged.
  const int ns = model_.stateDim(), n = ekf_.size();
  Eigen::VectorXd yh;
  Eigen::MatrixXd Gh;
  const double lambda = PatchModel::regauge(ekf_.x().head(ns), gauge, value, &yh, G ? &Gh : nullptr);
  if (!(lambda > 0.0)) return lambda;
  *y = ekf_.x();
  y->head(ns) = yh;
  if (G) {
    G->setIdentity(n, n);
    G->topLeftCorner(ns, ns) = Gh;
  }
  return lambda;
}

bool PatchFilter::advance(PatchFrameStats* fs) {
  const Eigen::Matrix<double, 7, 1> mp = ekf_.x().head<7>();
  const double beta = mp[6];
  const Eigen::Matrix3d Rk = incrementalRotation(mp.segment<3>(3));
  const Eigen::Vector3d t(mp[0], mp[1], mp[2] / beta);
  const Eigen::Vector3d tbar = t + (Eigen::Matrix3d::Identity() - Rk) * Eigen::Vector3d(0, 0, 1.0 / beta);
  // Structure into frame k (Murray-Shapiro + gauge); the maps (PatchCentres::State) are already there.
  const int ns = model_.stateDim(), n = ekf_.size();
  Eigen::VectorXd xh;
  Eigen::MatrixXd Fh;
  fs->transition = model_.transition(ekf_.x().head(ns), gauge_, gauge_value_, &xh, &Fh, &fs->lambda);
  if (fs->transition != MeasureStatus::Ok || !xh.allFinite() || !Fh.allFinite()) {
    if (fs->transition == MeasureStatus::Ok) fs->transition = MeasureStatus::NonFinite;
    fs->health |= kNonFiniteState;
    return false;
  }
  ekf_.mutableX().head(ns) = xh;
  Eigen::MatrixXd F = Eigen::MatrixXd::Identity(n, n);
  F.topLeftCorner(ns, ns) = Fh;
  ekf_.predict(F, Eigen::MatrixXd::Zero(n, n));
  T_ = Rk * T_ + scale_ * tbar;
  R_ = Rk * R_;
  scale_ *= fs->lambda;
  fs->health |= ekf_.health();
  return true;
}

void PatchFilter::predictMotion() {
  // Identity dynamics for the motion and beta (P += Q), q_structure on the structure, q_map on
  // the maps in the state.
  Eigen::VectorXd q = Eigen::VectorXd::Constant(ekf_.size(), opt_.q_structure);
  q.head<7>() = opt_.q_motion;
  if (mapsInState()) q.tail(6 * model_.numPatches()).setConstant(opt_.q_map);
  ekf_.predict(q);
  ++steps_;
}

double PatchFilter::annealInflation() const {
  // The first anneal_frames frames inflate R, linearly back to 1 (see the options).
  if (opt_.anneal_frames > 0 && steps_ < opt_.anneal_frames)
    return 1.0 + (opt_.anneal_factor - 1.0) * (1.0 - static_cast<double>(steps_) / opt_.anneal_frames);
  return 1.0;
}

bool PatchFilter::checkUpdate(const Eigen::VectorXd& x_prior, const Eigen::MatrixXd& P_prior, const std::vector<int>& used,
                              PatchFrameStats* fs) {
  fs->health = ekf_.health() | (fs->update.health & ~kTooFewMeasurements);
  if (opt_.beta_min > 0.0 && fs->update.applied) fs->beta_projected = ekf_.projectLowerBound(6, opt_.beta_min);
  if (!incrementalRotationValid(ekf_.x().segment<3>(3))) {  // rolled back
    ekf_.mutableX() = x_prior;
    ekf_.mutableP() = P_prior;
    fs->update.applied = false;
    fs->health |= kInvalidRotation;
    return false;
  }
  fs->used = used;
  return fs->health == kHealthy;
}

PatchFrameStats PatchFilter::stepState(const std::vector<AffineObservation>& obs) {
  PatchFrameStats fs;
  const int n = ekf_.size(), K = model_.numPatches();
  // 1. Motion prediction (identity dynamics) and structure noise.
  predictMotion();
  // 2. Each map carried into frame k by the exact inter-frame map: w' = (h, B A).
  std::vector<char> valid(K, 1);
  {
    const Eigen::VectorXd& x = ekf_.x();
    const Eigen::Matrix<double, 7, 1> m = x.head<7>();
    Eigen::VectorXd xn = x;
    Eigen::MatrixXd F = Eigen::MatrixXd::Identity(n, n);
    for (int k = 0; k < K; ++k) {
      const int is = PatchModel::structureIndex(k), im = mapIndex(k);
      Vector6d w1;
      PatchJacobian<6> J;
      Eigen::Matrix<double, 6, 6> Jw;
      const MeasureStatus st = PatchModel::composeMap(m, x.segment<3>(is), x.segment<6>(im), &w1, &J, &Jw);
      if (st != MeasureStatus::Ok || !w1.allFinite() || !J.allFinite() || !Jw.allFinite()) {
        valid[k] = 0;  // left where it was, and not measured this frame
        ++fs.invalid;
        if (fs.first_problem == MeasureStatus::Ok) fs.first_problem = st != MeasureStatus::Ok ? st : MeasureStatus::NonFinite;
        continue;
      }
      xn.segment<6>(im) = w1;
      F.block(im, 0, 6, 7) = J.leftCols<7>();
      F.block(im, is, 6, 3) = J.rightCols<3>();
      F.block<6, 6>(im, im) = Jw;
    }
    ekf_.mutableX() = xn;
    ekf_.predict(F, Eigen::MatrixXd::Zero(n, n));
  }
  // 3. Update: the tracker's cumulative maps, measured directly.
  std::vector<int> used;
  for (size_t i = 0; i < obs.size(); ++i) {
    const AffineObservation& o = obs[i];
    if (o.id < 0 || o.id >= K) {
      ++fs.invalid;
      if (fs.first_problem == MeasureStatus::Ok) fs.first_problem = MeasureStatus::UnknownFeature;
      continue;
    }
    if (!valid[o.id]) continue;
    if (!o.z.allFinite()) {
      ++fs.invalid;
      if (fs.first_problem == MeasureStatus::Ok) fs.first_problem = MeasureStatus::NonFinite;
      continue;
    }
    used.push_back(static_cast<int>(i));
  }
  const double inflate = annealInflation();
  const Vector6d var = (opt_.measurement_sd.array().square() * inflate).matrix();
  MeasurementBatch batch;
  batch.resize(static_cast<int>(used.size()), n, PatchModel::kMeasDim);
  for (size_t b = 0; b < used.size(); ++b) {
    const AffineObservation& o = obs[used[b]];
    const int r0 = 6 * static_cast<int>(b), im = mapIndex(o.id);
    batch.residual.segment<6>(r0) = o.z - ekf_.x().segment<6>(im);
    batch.H.block<6, 6>(r0, im).setIdentity();
    batch.R.block<6, 6>(r0, 0) = var.asDiagonal();
    batch.R.block<4, 4>(r0 + 2, 2) += inflate * o.map_cov;
  }
  const Eigen::VectorXd x_prior = ekf_.x();
  const Eigen::MatrixXd P_prior = ekf_.P();
  fs.update = ekf_.update(batch, opt_.update);
  if (!checkUpdate(x_prior, P_prior, used, &fs)) return fs;
  // 4. Pose, structure into frame k; the centres are the maps' (for outputs).
  if (!advance(&fs)) return fs;
  for (int k = 0; k < K; ++k) model_.setCentre(k, ekf_.x().segment<2>(mapIndex(k)));
  return fs;
}

PatchFrameStats PatchFilter::step(const std::vector<AffineObservation>& obs) {
  if (mapsInState()) return stepState(obs);
  PatchFrameStats fs;
  // 1. Prediction of the motion (identity dynamics) and structure noise.
  predictMotion();
  // 2. Update: one 6-row block per observed patch.
  std::vector<int> used;
  MeasurementBatch batch;
  linearize(ekf_.x(), obs, &batch, &used, &fs);
  const Eigen::VectorXd x_prior = ekf_.x();
  const Eigen::MatrixXd P_prior = ekf_.P();
  fs.update = ekf_.update(batch, opt_.update);
  const int iterations = steps_ <= opt_.warmup_frames ? std::max(opt_.iterations, opt_.warmup_iterations) : opt_.iterations;
  if (iterations > 1 && fs.update.applied) iterate(iterations, obs, used, x_prior, P_prior, &fs);
  if (!checkUpdate(x_prior, P_prior, used, &fs)) return fs;
  // 3. Centres into frame k, pose accumulation.
  const Eigen::Matrix<double, 7, 1> mp = ekf_.x().head<7>();
  std::vector<char> measured(model_.numPatches(), 0);
  std::vector<Eigen::Vector2d> measured_centre(model_.numPatches());
  for (size_t b = 0; b < used.size(); ++b) {
    const bool gated = b < fs.update.gated_mask.size() && fs.update.gated_mask[b];
    if (gated) continue;
    const int k = obs[used[b]].id;
    measured[k] = 1;
    measured_centre[k] = obs[used[b]].z.head<2>();
  }
  std::vector<Eigen::Vector2d> centres(model_.numPatches());
  std::vector<Eigen::Matrix2d> covs = centre_cov_;
  fs.posterior_z.assign(model_.numPatches(), Vector6d::Constant(std::nan("")));
  fs.posterior_cov.assign(model_.numPatches(), Eigen::Matrix<double, 6, 6>::Zero());
  const double s2 = opt_.centre_sd * opt_.centre_sd;
  for (int k = 0; k < model_.numPatches(); ++k) {
    Vector6d zp;
    PatchJacobian<6> J;
    const int is = PatchModel::structureIndex(k);
    const MeasureStatus st =
        PatchModel::measure(opt_.measurement, mp, ekf_.x().segment<3>(is), model_.centre(k), &zp, &J);
    const bool predicted = st == MeasureStatus::Ok;
    std::vector<int> cols{0, 1, 2, 3, 4, 5, 6, is, is + 1, is + 2};
    if (predicted) {
      fs.posterior_z[k] = zp;
      fs.posterior_cov[k] = J * ekf_.P()(cols, cols) * J.transpose();
    }
    if (opt_.centres == PatchCentres::Measured || !predicted) {
      centres[k] = measured[k] ? measured_centre[k] : predicted ? Eigen::Vector2d(zp.head<2>()) : model_.centre(k);
      covs[k] = Eigen::Matrix2d::Identity() * s2;
      continue;
    }
    if (opt_.centres == PatchCentres::Predicted) {
      centres[k] = zp.head<2>();
      continue;
    }
    // Fused: prediction with its covariance, then the measured centre.
    Eigen::Matrix2d A;
    A << zp[2], zp[3], zp[4], zp[5];
    const Eigen::Matrix2d Cp = A * centre_cov_[k] * A.transpose() + fs.posterior_cov[k].topLeftCorner<2, 2>();
    if (!measured[k]) {  // gated or not observed: restart from the measurement if there is one
      bool seen = false;
      for (size_t b = 0; b < used.size(); ++b)
        if (obs[used[b]].id == k) seen = true, centres[k] = obs[used[b]].z.head<2>();
      if (seen) covs[k] = Eigen::Matrix2d::Identity() * s2;
      else centres[k] = zp.head<2>(), covs[k] = Cp;
      continue;
    }
    const Eigen::Matrix2d G = Cp * (Cp + Eigen::Matrix2d::Identity() * s2).inverse();
    centres[k] = zp.head<2>() + G * (measured_centre[k] - zp.head<2>());
    const Eigen::Matrix2d C = (Eigen::Matrix2d::Identity() - G) * Cp;
    covs[k] = 0.5 * (C + C.transpose());
  }
  // 4. Pose, structure into frame k (Murray-Shapiro + gauge).
  if (!advance(&fs)) return fs;
  for (int k = 0; k < model_.numPatches(); ++k) model_.setCentre(k, centres[k]);
  centre_cov_ = covs;
  return fs;
}

void PatchFilter::linearize(const Eigen::VectorXd& x, const std::vector<AffineObservation>& obs, MeasurementBatch* batch,
                            std::vector<int>* used, PatchFrameStats* fs) const {
  const int n = static_cast<int>(x.size());
  const Eigen::Matrix<double, 7, 1> m = x.head<7>();
  used->clear();
  std::vector<Vector6d> residuals, predicted;
  std::vector<PatchJacobian<6>> jacobians;
  for (size_t i = 0; i < obs.size(); ++i) {
    const AffineObservation& o = obs[i];
    if (o.id < 0 || o.id >= model_.numPatches()) {
      ++fs->invalid;
      if (fs->first_problem == MeasureStatus::Ok) fs->first_problem = MeasureStatus::UnknownFeature;
      continue;
    }
    Vector6d zp;
    PatchJacobian<6> J;
    const MeasureStatus st = PatchModel::measure(opt_.measurement, m, x.segment<3>(PatchModel::structureIndex(o.id)),
                                                 model_.centre(o.id), &zp, &J);
    if (st != MeasureStatus::Ok || !o.z.allFinite()) {
      ++fs->invalid;
      if (fs->first_problem == MeasureStatus::Ok)
        fs->first_problem = st != MeasureStatus::Ok ? st : MeasureStatus::NonFinite;
      continue;
    }
    used->push_back(static_cast<int>(i));
    residuals.push_back(o.z - zp);
    predicted.push_back(zp);
    jacobians.push_back(J);
  }
  batch->resize(static_cast<int>(used->size()), n, PatchModel::kMeasDim);
  const double inflate = annealInflation();
  const Vector6d sd = opt_.measurement_sd * std::sqrt(inflate);
  for (size_t b = 0; b < used->size(); ++b) {
    const int k = obs[(*used)[b]].id, r0 = 6 * static_cast<int>(b);
    batch->residual.segment<6>(r0) = residuals[b];
    batch->H.block(r0, 0, 6, 7) = jacobians[b].leftCols<7>();
    batch->H.block(r0, PatchModel::structureIndex(k), 6, 3) = jacobians[b].rightCols<3>();
    batch->R.block<6, 6>(r0, 0) = sd.array().square().matrix().asDiagonal();
    batch->R.block<4, 4>(r0 + 2, 2) += inflate * obs[(*used)[b]].map_cov;
    // The previous centre is uncertain (covariance C): its error moves the predicted centre by
    // A (c - c_true), A = dh/dc; dA/dc is second order and left out.
    if (opt_.centres != PatchCentres::Predicted) {
      const Vector6d& zp = predicted[b];
      Eigen::Matrix2d A;
      A << zp[2], zp[3], zp[4], zp[5];
      batch->R.block<2, 2>(r0, 0) += inflate * A * centre_cov_[k] * A.transpose();
    }
  }
}

void PatchFilter::iterate(int iterations, const std::vector<AffineObservation>& obs, const std::vector<int>& used,
                          const Eigen::VectorXd& x_prior, const Eigen::MatrixXd& P_prior, PatchFrameStats* fs) {
  // Iterated EKF with backtracking (rsfm::iteratedUpdate, 5 step sizes): Gauss-Newton on the MAP
  // cost over the blocks accepted by the first update; each Gauss-Newton point is the update of
  // the prior linearized at the current iterate x_i (residual z - h(x_i) - H_i (x^- - x_i)).
  std::vector<char> accepted(obs.size(), 0);
  for (size_t b = 0; b < used.size(); ++b)
    if (b >= fs->update.gated_mask.size() || !fs->update.gated_mask[b]) accepted[used[b]] = 1;
  // The cost uses the same R as the update (annealing, centre and map uncertainties included).
  auto cost = [&](const Eigen::VectorXd& x, double* out) {
    if (!x.allFinite() || !incrementalRotationValid(x.segment<3>(3))) return false;
    MeasurementBatch b;
    std::vector<int> u;
    PatchFrameStats tmp;
    linearize(x, obs, &b, &u, &tmp);
    if (u != used) return false;
    double c = 0.0;
    for (size_t k = 0; k < u.size(); ++k) {
      if (!accepted[u[k]]) continue;
      const Vector6d r = b.residual.segment<6>(6 * k);
      c += r.dot(b.R.block<6, 6>(6 * k, 0).ldlt().solve(r));
    }
    *out = c;
    return true;
  };
  auto gaussNewtonPoint = [&](const Eigen::VectorXd& x_lin) {
    MeasurementBatch relin;
    std::vector<int> used_i;
    PatchFrameStats tmp;
    linearize(x_lin, obs, &relin, &used_i, &tmp);
    if (used_i != used) return false;
    relin.residual += relin.H * (x_lin - x_prior);
    for (size_t b = 0; b < used.size(); ++b)
      if (!accepted[used[b]]) relin.R.block<6, 6>(6 * b, 0) *= 1e12;  // keep the first update's gate decisions
    ekf_.mutableX() = x_prior;
    ekf_.mutableP() = P_prior;
    UpdateOptions uo = opt_.update;
    uo.gate_probability = 0.0;
    return ekf_.update(relin, uo).applied;
  };
  const int n = iteratedUpdate(&ekf_, iterations, opt_.iteration_tol, 5, x_prior, P_prior, cost, gaussNewtonPoint);
  if (n > 0) fs->iterations = n;
}

int PatchFilter::addPatch(const Eigen::Vector2d& centre, const Eigen::Vector3d& s0, const Eigen::Matrix3d& P0) {
  if (!mapsInState()) {
    ekf_.augment(s0, P0, Eigen::MatrixXd::Zero(3, ekf_.size()));
  } else {
    // Appended as [s0, w0], then s0 moved to the end of the structure block.
    const int n = ekf_.size(), ns = model_.stateDim();
    Eigen::VectorXd xa(9);
    xa << s0, centre, 1.0, 0.0, 0.0, 1.0;
    Eigen::MatrixXd Pa = Eigen::MatrixXd::Zero(9, 9);
    Pa.topLeftCorner<3, 3>() = P0;
    Pa.bottomRightCorner<6, 6>() = initialMapCovariance();
    ekf_.augment(xa, Pa, Eigen::MatrixXd::Zero(9, n));
    std::vector<int> order;
    for (int i = 0; i < ns; ++i) order.push_back(i);
    for (int i = 0; i < 3; ++i) order.push_back(n + i);
    for (int i = ns; i < n; ++i) order.push_back(i);
    for (int i = 0; i < 6; ++i) order.push_back(n + 3 + i);
    ekf_.reorder(order);
  }
  centre_cov_.push_back(Eigen::Matrix2d::Identity() * opt_.centre_sd * opt_.centre_sd);
  return model_.addPatch(centre);
}

bool PatchFilter::removePatch(int slot) {
  if (model_.numPatches() <= 1 || slot < 0 || slot >= model_.numPatches()) return false;
  if (slot == gauge_) {
    // New gauge: the best-determined p4 among the others.
    int best = -1;
    for (int k = 0; k < model_.numPatches(); ++k) {
      if (k == slot) continue;
      const double v = ekf_.P()(PatchModel::p4Index(k), PatchModel::p4Index(k));
      if (best < 0 || v < ekf_.P()(PatchModel::p4Index(best), PatchModel::p4Index(best))) best = k;
    }
    const int ib = PatchModel::p4Index(best);
    Eigen::VectorXd y;
    Eigen::MatrixXd G;
    if (!(regaugeState(best, ekf_.x()[ib], &y, &G) > 0.0)) return false;
    ekf_.setFixed(PatchModel::p4Index(gauge_), false);
    Eigen::MatrixXd P = G * ekf_.P() * G.transpose();
    ekf_.mutableP() = 0.5 * (P + P.transpose());
    ekf_.mutableX() = y;
    ekf_.setFixed(ib, true);
    gauge_ = best;
    gauge_value_ = y[ib];
  }
  const int i = PatchModel::structureIndex(slot);
  std::vector<int> drop{i, i + 1, i + 2};
  if (mapsInState())
    for (int j = 0; j < 6; ++j) drop.push_back(mapIndex(slot) + j);
  ekf_.remove(drop);
  model_.removePatch(slot);
  centre_cov_.erase(centre_cov_.begin() + slot);
  if (gauge_ > slot) --gauge_;
  return true;
}

}  // namespace rsfm
