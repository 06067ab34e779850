// Online odometry self-calibration: the systematic part of wheel odometry's error, estimated
// from scan matches (the pose-graph mapper's keyframe matches, the RBPF's best particle) and
// taken out of every odometry step before the mapper uses it.
//
// Model (per step, in the step's start frame; x forward, y left, true motion (x, y, theta)):
//   odom_x     = (1 + x_scale) x                 wheel radius / encoder scale error
//   odom_y     = y + y_per_x x                   lateral creep while driving forward
//   odom_theta = (1 + theta_scale) theta + theta_per_x x
//                                                 track-width error; heading drift per metre
//                                                 forward (unequal wheels, omni-roller slip)
// These are the classic systematic odometry errors (Borenstein and Feng's UMBmark names the
// first and last for differential drives); an omni base shows the same four, usually larger.
// Correct() inverts the model on one raw step. The estimate is a linear least-squares fit of
// raw odometry between two scans (composed from many steps, treated as one) against the scan
// matcher's relative pose of the same pair: the match does not use odometry beyond its search
// centre, so the fit does not chase its own output. Pairs whose residual is far from the
// current fit are left out, and the result is bounded. The fit uses the newest `max_pairs`
// pairs, so it follows slow changes (tyre wear, load). (In the RBPF the match starts from the
// calibrated prediction and its prior pulls towards it, so along weakly observed directions the
// fit leans a little towards its own value: slower to converge, not biased at convergence.)
//
// Noise scale (adapt_noise): the configured odometry covariance of each pair is a model; the
// residuals of the calibrated odometry against the matches say how large it really is. The
// scale is median(r^T Sigma^-1 r) / 2.366 (the median of a chi-square with 3 degrees of freedom),
// so a model that is 10x too loose gets a scale near 0.1. The residual also holds the match's own
// error, so the scale errs on the loose side.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "omni/common/config.h"
#include "omni/common/geometry.h"

namespace omni {

struct OdometryCalibration {
  double x_scale = 0.0;
  double y_per_x = 0.0;
  double theta_scale = 0.0;
  double theta_per_x = 0.0;  // rad per metre forward
  // The true step for a raw odometry step (the model above, inverted).
  Pose2 Correct(const Pose2& raw) const;
  // The raw step the model predicts for a true step.
  Pose2 Distort(const Pose2& truth) const;
  bool IsIdentity() const {
    return x_scale == 0.0 && y_per_x == 0.0 && theta_scale == 0.0 && theta_per_x == 0.0;
  }
};

struct OdometryCalibratorOptions {
  bool enabled = true;               // the mapper calibrates at all (the calibrator ignores it)
  int min_pairs = 15;                // keyframe pairs before the first estimate is used
  double min_forward_m = 5.0;        // ... and this much forward travel among them
  int update_every_pairs = 10;       // re-estimate after this many new pairs
  double max_abs_scale = 0.15;       // |x_scale|, |theta_scale| at most (clamped)
  double max_abs_y_per_x = 0.1;      // |y_per_x| at most
  double max_abs_theta_per_x = 0.1;  // |theta_per_x| (rad/m) at most
  // A pair whose residual after the current fit exceeds these is left out of the fit.
  double gate_xy_m = 0.15;
  double gate_theta_rad = 0.1;
  // Relink: every global optimisation recomputes the odometry factors still covered by the
  // odometry buffer with the current calibration (older factors keep theirs).
  bool relink_on_global = true;
  int max_pairs = 5000;  // the fit uses the newest this many pairs
  // Scale the configured odometry noise by the residuals' median chi-square (see above),
  // clamped to [min_noise_scale, max_noise_scale].
  bool adapt_noise = false;
  double min_noise_scale = 0.01;
  double max_noise_scale = 10.0;
};

// Reads the options' keys (all optional) from a config section (`odometry_calibration:` in
// the pose-graph and RBPF configs); errors name the key. Without `graph_keys` the keys only the
// pose graph uses (relink_on_global, adapt_noise, min/max_noise_scale) are not read, so a
// config that sets them is an error (unknown key) instead of a silent no-op.
void ReadOdometryCalibratorOptions(ConfigReader& section, OdometryCalibratorOptions* o,
                                   bool graph_keys = true);

class OdometryCalibrator {
 public:
  explicit OdometryCalibrator(OdometryCalibratorOptions o = {}) : o_(o) {}
  // One keyframe pair: the raw odometry from keyframe a to b (composed steps), the scan
  // matcher's pose of b in a's frame, and the configured (unscaled) odometry covariance of the
  // interval. Returns true when the pair was used.
  bool AddPair(const Pose2& raw, const Pose2& matched,
               const Eigen::Matrix3d& model_covariance = Eigen::Matrix3d::Identity());
  // The current estimate (identity until min_pairs / min_forward_m are reached).
  const OdometryCalibration& calibration() const { return cal_; }
  // True once an estimate is in use; counts.
  bool active() const { return active_; }
  // Factor for the configured odometry noise (1 until active, or without adapt_noise).
  double noise_scale() const { return noise_scale_; }
  // What the residuals say the factor should be (computed with or without adapt_noise; 0 until
  // active): far below 1 means the configured odometry noise is much looser than the odometry.
  double suggested_noise_scale() const { return suggested_noise_scale_; }
  int64_t pairs_used() const { return used_; }
  int64_t pairs_gated() const { return gated_; }
  int64_t updates() const { return updates_; }

 private:
  void Solve();

  struct Pair {
    Pose2 raw, matched;
    Eigen::Matrix3d information;  // of the configured model
  };
  OdometryCalibratorOptions o_;
  OdometryCalibration cal_;
  double noise_scale_ = 1.0, suggested_noise_scale_ = 0.0;
  bool active_ = false;
  int64_t used_ = 0, gated_ = 0, updates_ = 0, since_update_ = 0;
  std::deque<Pair> pairs_;
};

// The calibrator's state as heartbeat counters (name, reader): matches used / left out,
// refits, and the fit in parts per million. The readers refer to `oc`, which must outlive them.
std::vector<std::pair<std::string, std::function<int64_t()>>> OdometryCalibrationCounters(
    const OdometryCalibrator& oc);

}  // namespace omni
