#include "omni/pose_graph_mapper/node_removal.h"

#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "omni/pose_graph_mapper/chi2.h"
#include "omni/pose_graph_mapper/cost_functions.h"

namespace omni::pgm {
namespace {

// EdgeError2(z, a, b) and its Jacobians over the optimiser's (x, y, theta) blocks of a and b:
// the global solve's own cost function, with identity information.
Eigen::Vector3d ErrorJacobians(const Pose2& z, const Pose2& a, const Pose2& b, Eigen::Matrix3d* ja,
                               Eigen::Matrix3d* jb) {
  const RelativePose2Cost cost(z, Eigen::Matrix3d::Identity());
  const double pa[3] = {a.x, a.y, a.theta}, pb[3] = {b.x, b.y, b.theta};
  const double* params[2] = {pa, pb};
  Eigen::Vector3d e;
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> ra, rb;
  double* jacobians[2] = {ra.data(), rb.data()};
  cost.Evaluate(params, e.data(), jacobians);
  *ja = ra;
  *jb = rb;
  return e;
}

}  // namespace

Result<std::vector<RelativeFactor2>> MarginalizeNode(int node,
                                                     const std::vector<RelativeFactor2>& factors,
                                                     const std::map<int, Pose2>& estimates,
                                                     const std::map<int, int64_t>& order) {
  auto estimate = [&](int id) -> const Pose2* {
    const auto it = estimates.find(id);
    return it == estimates.end() ? nullptr : &it->second;
  };
  // Block 0 is the removed node, blocks 1..m its neighbours.
  std::map<int, int> block{{node, 0}};
  std::vector<int> ids{node};
  for (const auto& f : factors) {
    if (f.from != node && f.to != node)
      return MakeError(ErrorCode::kInvalidArgument, "a factor does not touch the removed node");
    for (int id : {f.from, f.to}) {
      if (!estimate(id) || order.find(id) == order.end())
        return MakeError(ErrorCode::kInvalidArgument,
                         "no estimate or order for node " + std::to_string(id));
      if (block.emplace(id, static_cast<int>(ids.size())).second) ids.push_back(id);
    }
  }
  const int m = static_cast<int>(ids.size()) - 1;
  if (m <= 1) return std::vector<RelativeFactor2>{};  // a leaf: its factors fix nothing else

  const int n = 3 * (m + 1);
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd grad = Eigen::VectorXd::Zero(n);  // J^T Omega e: the factors' pull
  for (const auto& f : factors) {
    Eigen::Matrix3d ja, jb;
    const Pose2 &a = *estimate(f.from), &b = *estimate(f.to);
    const Eigen::Vector3d e = ErrorJacobians(f.z, a, b, &ja, &jb);
    const Eigen::Matrix3d w = 0.5 * (f.information + f.information.transpose());
    const int ia = 3 * block.at(f.from), ib = 3 * block.at(f.to);
    grad.segment<3>(ia) += ja.transpose() * w * e;
    grad.segment<3>(ib) += jb.transpose() * w * e;
    h.block<3, 3>(ia, ia) += ja.transpose() * w * ja;
    h.block<3, 3>(ia, ib) += ja.transpose() * w * jb;
    h.block<3, 3>(ib, ia) += jb.transpose() * w * ja;
    h.block<3, 3>(ib, ib) += jb.transpose() * w * jb;
  }
  // Schur complement of the removed node.
  const Eigen::Matrix3d hrr = h.topLeftCorner<3, 3>();
  const Eigen::FullPivLU<Eigen::Matrix3d> lu(hrr);
  if (!lu.isInvertible())
    return MakeError(ErrorCode::kOutOfRange, "the node's factors do not fix its pose");
  const Eigen::MatrixXd hnr = h.bottomLeftCorner(n - 3, 3);
  const Eigen::MatrixXd lambda =
      h.bottomRightCorner(n - 3, n - 3) - hnr * lu.solve(hnr.transpose());
  const Eigen::VectorXd eta = grad.tail(n - 3) - hnr * lu.solve(Eigen::Vector3d(grad.head<3>()));

  // Relative poses do not depend on the gauge: hold the first neighbour fixed and invert.
  const int g = 3 * (m - 1);
  const Eigen::MatrixXd held =
      0.5 * (lambda.bottomRightCorner(g, g) + lambda.bottomRightCorner(g, g).transpose());
  const Eigen::LLT<Eigen::MatrixXd> llt(held);
  if (llt.info() != Eigen::Success)
    return MakeError(ErrorCode::kOutOfRange,
                     "the marginal does not fix the neighbours relative to each other");
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(3 * m, 3 * m);
  cov.bottomRightCorner(g, g) = llt.solve(Eigen::MatrixXd::Identity(g, g));
  // Each pair's relative pose: its covariance (in EdgeError2's frame) and weight.
  struct Pair {
    double weight = -std::numeric_limits<double>::infinity();
    Eigen::Matrix3d covariance;
  };
  std::vector<Pair> pairs(static_cast<size_t>(m * m));
  auto older_first = [&](int i, int j) {
    return order.at(ids[static_cast<size_t>(i)]) <= order.at(ids[static_cast<size_t>(j)]);
  };
  for (int i = 1; i <= m; ++i) {
    for (int j = i + 1; j <= m; ++j) {
      const int a = older_first(i, j) ? i : j, b = a == i ? j : i;
      const Pose2& pa = *estimate(ids[static_cast<size_t>(a)]);
      const Pose2& pb = *estimate(ids[static_cast<size_t>(b)]);
      Eigen::Matrix3d ja, jb;
      ErrorJacobians(pa.Between(pb), pa, pb, &ja, &jb);
      Eigen::Matrix<double, 3, 6> jab;
      jab << ja, jb;
      Eigen::Matrix<double, 6, 6> joint;
      const int ca = 3 * (a - 1), cb = 3 * (b - 1);
      joint << cov.block<3, 3>(ca, ca), cov.block<3, 3>(ca, cb), cov.block<3, 3>(cb, ca),
          cov.block<3, 3>(cb, cb);
      Pair p;
      p.covariance = jab * joint * jab.transpose();
      p.covariance = 0.5 * (p.covariance + p.covariance.transpose());
      const double det = p.covariance.determinant();
      if (det > 0 && std::isfinite(det)) p.weight = -std::log(det);
      pairs[static_cast<size_t>((i - 1) * m + (j - 1))] = p;
      pairs[static_cast<size_t>((j - 1) * m + (i - 1))] = p;
    }
  }

  // Prim's maximum spanning tree over the neighbours.
  std::vector<char> in(static_cast<size_t>(m), 0);
  std::vector<double> best(static_cast<size_t>(m), -std::numeric_limits<double>::infinity());
  std::vector<int> parent(static_cast<size_t>(m), -1);
  in[0] = 1;
  for (int j = 1; j < m; ++j) {
    best[static_cast<size_t>(j)] = pairs[static_cast<size_t>(j)].weight;
    parent[static_cast<size_t>(j)] = 0;
  }
  std::vector<RelativeFactor2> out;
  for (int added = 1; added < m; ++added) {
    int next = -1;
    for (int j = 0; j < m; ++j)
      if (!in[static_cast<size_t>(j)] && std::isfinite(best[static_cast<size_t>(j)]) &&
          (next < 0 || best[static_cast<size_t>(j)] > best[static_cast<size_t>(next)]))
        next = j;
    if (next < 0)
      return MakeError(ErrorCode::kOutOfRange,
                       "a neighbour's relative pose has no finite covariance");
    in[static_cast<size_t>(next)] = 1;
    const int i = parent[static_cast<size_t>(next)];
    const Pair& p = pairs[static_cast<size_t>(i * m + next)];
    const int a = older_first(i + 1, next + 1) ? i + 1 : next + 1,
              b = a == i + 1 ? next + 1 : i + 1;
    const int ida = ids[static_cast<size_t>(a)], idb = ids[static_cast<size_t>(b)];
    const Eigen::Matrix3d info = p.covariance.inverse();
    out.push_back({ida, idb, Pose2(), 0.5 * (info + info.transpose())});
    for (int j = 0; j < m; ++j) {
      const double w = pairs[static_cast<size_t>(next * m + j)].weight;
      if (!in[static_cast<size_t>(j)] && w > best[static_cast<size_t>(j)]) {
        best[static_cast<size_t>(j)] = w;
        parent[static_cast<size_t>(j)] = next;
      }
    }
  }

  // The tree's measurements: the neighbours' poses at which the tree pulls on them, at the
  // current estimates, exactly as the removed factors did (the same gradient, eta): with the
  // tree's Hessian T, estimates - T^-1 eta, with the first neighbour held. The graph's optimum
  // then stays where it was to first order; only how later corrections spread is approximated.
  // (Measuring the marginal's own mean, estimates - Lambda^-1 eta, moves it by the difference
  // between T and Lambda.)
  Eigen::MatrixXd tree_h = Eigen::MatrixXd::Zero(g, g);
  for (const auto& f : out) {
    const int a = block.at(f.from) - 2, b = block.at(f.to) - 2;  // -1: the held neighbour
    const Pose2 &pa = *estimate(f.from), &pb = *estimate(f.to);
    Eigen::Matrix3d ja, jb;
    ErrorJacobians(pa.Between(pb), pa, pb, &ja, &jb);
    if (a >= 0) tree_h.block<3, 3>(3 * a, 3 * a) += ja.transpose() * f.information * ja;
    if (b >= 0) tree_h.block<3, 3>(3 * b, 3 * b) += jb.transpose() * f.information * jb;
    if (a >= 0 && b >= 0) {
      tree_h.block<3, 3>(3 * a, 3 * b) += ja.transpose() * f.information * jb;
      tree_h.block<3, 3>(3 * b, 3 * a) += jb.transpose() * f.information * ja;
    }
  }
  const Eigen::LLT<Eigen::MatrixXd> tree_llt(tree_h);
  if (tree_llt.info() != Eigen::Success)
    return MakeError(ErrorCode::kOutOfRange, "the tree does not fix the neighbours");
  const Eigen::VectorXd shift = -tree_llt.solve(Eigen::VectorXd(eta.tail(g)));
  std::map<int, Pose2> pulled;
  for (int i = 1; i <= m; ++i) {
    Pose2 p = *estimate(ids[static_cast<size_t>(i)]);
    if (i > 1) {
      const Eigen::Vector3d d = shift.segment<3>(3 * (i - 2));
      p = Pose2(p.x + d.x(), p.y + d.y(), WrapAngle(p.theta + d.z()));
    }
    pulled[ids[static_cast<size_t>(i)]] = p;
  }
  for (auto& f : out) f.z = pulled.at(f.from).Between(pulled.at(f.to));
  return out;
}

double LossWeight(const std::string& loss, double scale, double s2) {
  const double c2 = scale * scale;
  if (loss == "cauchy") return 1 / (1 + s2 / c2);             // rho = c2 log(1 + s / c2)
  if (loss == "huber" && s2 > c2) return std::sqrt(c2 / s2);  // rho = 2 c sqrt(s) - c2
  return 1;
}

RelativeFactor2 MergeRelativeFactors(const RelativeFactor2& f1, const RelativeFactor2& f2,
                                     const Pose2& from, const Pose2& to) {
  // Both residuals linearised at the estimates (the same Jacobian to first order): the sum is one
  // factor with the summed information whose residual there is their information-weighted mean.
  const Eigen::Matrix3d w = f1.information + f2.information;
  const Eigen::Vector3d mu = w.ldlt().solve(f1.information * EdgeError2(f1.z, from, to) +
                                            f2.information * EdgeError2(f2.z, from, to));
  RelativeFactor2 out = f1;
  // EdgeError2(ab * d^-1, from, to) = d exactly, for d = (mu_x, mu_y, mu_theta).
  out.z = from.Between(to) * Pose2(mu.x(), mu.y(), mu.z()).Inverse();
  out.information = 0.5 * (w + w.transpose());
  return out;
}

}  // namespace omni::pgm
