#include "omni/pose_graph_mapper/initialization.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <unordered_map>
#include <utility>
#include <vector>

#include <ceres/internal/config.h>  // CERES_NO_SUITESPARSE

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>

// CHOLMOD comes with Ceres' SuiteSparse back end (the batch optimiser's sparse Cholesky): its
// supernodal factorisation (dense kernels on the supernodes) is several times faster than
// Eigen's simplicial one on the 3D chordal systems. Without it, Eigen's is used.
#if !defined(CERES_NO_SUITESPARSE) && __has_include(<suitesparse/cholmod.h>)
#include <suitesparse/cholmod.h>
#define OMNI_PGM_HAVE_CHOLMOD 1
#endif

namespace omni::pgm {
namespace {

// Dense vertex indices and, per vertex, the incident edges (2D or 3D, whichever the graph has).
struct Topology {
  std::unordered_map<int, int> index;      // id -> dense index
  std::vector<std::pair<int, int>> edges;  // dense (from, to)
  std::vector<std::vector<int>> incident;  // dense vertex -> edge numbers
};

Topology BuildTopology(const io::PoseGraph& g) {
  Topology t;
  const bool is3d = g.is_3d();
  const size_t n = is3d ? g.vertices3.size() : g.vertices2.size();
  for (size_t i = 0; i < n; ++i)
    t.index[is3d ? g.vertices3[i].id : g.vertices2[i].id] = static_cast<int>(i);
  t.incident.resize(n);
  const size_t m = is3d ? g.edges3.size() : g.edges2.size();
  for (size_t k = 0; k < m; ++k) {
    const int from = is3d ? g.edges3[k].from : g.edges2[k].from;
    const int to = is3d ? g.edges3[k].to : g.edges2[k].to;
    const int a = t.index.at(from), b = t.index.at(to);
    t.edges.emplace_back(a, b);
    t.incident[a].push_back(static_cast<int>(k));
    if (b != a) t.incident[b].push_back(static_cast<int>(k));
  }
  return t;
}

// Breadth-first order from root; parent_edge[v] = edge that reached v (-1 for the root).
// Returns an error naming an unreachable vertex id.
Status Bfs(const io::PoseGraph& g, const Topology& t, int root_id, std::vector<int>* order,
           std::vector<int>* parent_edge) {
  auto it = t.index.find(root_id);
  if (it == t.index.end())
    return MakeError(ErrorCode::kInvalidArgument,
                     "root vertex " + std::to_string(root_id) + " is not in the graph");
  const size_t n = t.incident.size();
  parent_edge->assign(n, -2);
  order->clear();
  std::deque<int> q{it->second};
  (*parent_edge)[it->second] = -1;
  while (!q.empty()) {
    const int v = q.front();
    q.pop_front();
    order->push_back(v);
    for (int k : t.incident[v]) {
      const int w = t.edges[k].first == v ? t.edges[k].second : t.edges[k].first;
      if ((*parent_edge)[w] != -2) continue;
      (*parent_edge)[w] = k;
      q.push_back(w);
    }
  }
  if (order->size() != n) {
    for (const auto& [id, idx] : t.index)
      if ((*parent_edge)[idx] == -2)
        return MakeError(ErrorCode::kInvalidArgument,
                         "the graph is not connected: vertex " + std::to_string(id) +
                             " cannot be reached from root " + std::to_string(root_id) +
                             (g.is_3d() ? " (3D)" : ""));
  }
  return Status::Ok();
}

// Sparse linear least squares min ||A x - b||^2 where some variables are fixed to known values.
class LinearLeastSquares {
 public:
  explicit LinearLeastSquares(int num_vars) : col_(num_vars, 0), fixed_(num_vars, 0.0) {}
  void Fix(int var, double value) {
    col_[var] = -1;
    fixed_[var] = value;
  }
  void AddRow(const std::vector<std::pair<int, double>>& terms, double rhs) {
    rows_.push_back({terms, rhs});
  }
  // Returns all variable values (fixed ones as given).
  Result<std::vector<double>> Solve() {
    int cols = 0;
    for (auto& c : col_) c = c == -1 ? -1 : cols++;
    std::vector<Eigen::Triplet<double>> trips;
    Eigen::VectorXd b(rows_.size());
    for (size_t r = 0; r < rows_.size(); ++r) {
      double rhs = rows_[r].second;
      for (const auto& [var, coef] : rows_[r].first) {
        if (col_[var] < 0)
          rhs -= coef * fixed_[var];
        else
          trips.emplace_back(static_cast<int>(r), col_[var], coef);
      }
      b[r] = rhs;
    }
    Eigen::SparseMatrix<double> a(static_cast<int>(rows_.size()), cols);
    a.setFromTriplets(trips.begin(), trips.end());
    const Eigen::SparseMatrix<double> at = a.transpose();
    Eigen::SparseMatrix<double> h = at * a;
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(h);
    if (ldlt.info() != Eigen::Success)
      return MakeError(ErrorCode::kInvalidArgument,
                       "linear initialisation is singular (is the graph connected?)");
    const Eigen::VectorXd x = ldlt.solve(at * b);
    std::vector<double> out(col_.size());
    for (size_t v = 0; v < col_.size(); ++v) out[v] = col_[v] < 0 ? fixed_[v] : x[col_[v]];
    return out;
  }

 private:
  std::vector<int> col_;
  std::vector<double> fixed_;
  std::vector<std::pair<std::vector<std::pair<int, double>>, double>> rows_;
};

// Information of a sub-vector after marginalising the rest: inverse of the covariance block.
template <int N, int K>
Eigen::Matrix<double, K, K> MarginalInfo(const Eigen::Matrix<double, N, N>& info, int start) {
  const Eigen::Matrix<double, N, N> cov = info.inverse();
  return cov.template block<K, K>(start, start).inverse();
}

template <int K>
Eigen::Matrix<double, K, K> SqrtOf(const Eigen::Matrix<double, K, K>& m) {
  Eigen::LLT<Eigen::Matrix<double, K, K>> llt(0.5 * (m + m.transpose()));
  return llt.matrixU();
}

Status Chordal2(io::PoseGraph* g, const Topology& t, int root) {
  std::vector<int> order, parent;
  if (Status s = Bfs(*g, t, g->vertices2[root].id, &order, &parent); !s.ok()) return s;
  const int n = static_cast<int>(g->vertices2.size());
  // Unwrapped tree orientations.
  std::vector<double> th_tree(n, 0.0);
  th_tree[root] = g->vertices2[root].pose.theta;
  for (int v : order) {
    if (parent[v] < 0) continue;
    const auto& e = g->edges2[parent[v]];
    const auto [a, b] = t.edges[parent[v]];
    if (b == v)
      th_tree[v] = th_tree[a] + e.measurement.theta;
    else
      th_tree[v] = th_tree[b] - e.measurement.theta;
  }
  // Orientations: th_b - th_a = dth + 2 pi k, k from the tree estimate.
  LinearLeastSquares rot(n);
  rot.Fix(root, th_tree[root]);
  for (size_t k = 0; k < g->edges2.size(); ++k) {
    const auto& e = g->edges2[k];
    const auto [a, b] = t.edges[k];
    if (a == b) continue;
    const double d = e.measurement.theta;
    const double wraps = std::round((th_tree[b] - th_tree[a] - d) / (2 * M_PI));
    const double w = std::sqrt(1.0 / e.information.inverse()(2, 2));
    rot.AddRow({{a, -w}, {b, w}}, w * (d + 2 * M_PI * wraps));
  }
  auto th = rot.Solve();
  if (!th.ok()) return th.error();
  // Positions: p_b - p_a = R(th_a) p_z, weighted by the rotated marginal xy information.
  LinearLeastSquares pos(2 * n);
  pos.Fix(2 * root, g->vertices2[root].pose.x);
  pos.Fix(2 * root + 1, g->vertices2[root].pose.y);
  for (size_t k = 0; k < g->edges2.size(); ++k) {
    const auto& e = g->edges2[k];
    const auto [a, b] = t.edges[k];
    if (a == b) continue;
    const double c = std::cos((*th)[a]), s = std::sin((*th)[a]);
    Eigen::Matrix2d r;
    r << c, -s, s, c;
    const Eigen::Matrix2d info = r * MarginalInfo<3, 2>(e.information, 0) * r.transpose();
    const Eigen::Matrix2d sq = SqrtOf<2>(info);
    const Eigen::Vector2d rhs = sq * (r * Eigen::Vector2d(e.measurement.x, e.measurement.y));
    for (int row = 0; row < 2; ++row)
      pos.AddRow({{2 * a, -sq(row, 0)},
                  {2 * a + 1, -sq(row, 1)},
                  {2 * b, sq(row, 0)},
                  {2 * b + 1, sq(row, 1)}},
                 rhs[row]);
  }
  auto p = pos.Solve();
  if (!p.ok()) return p.error();
  for (int v = 0; v < n; ++v)
    g->vertices2[v].pose = Pose2((*p)[2 * v], (*p)[2 * v + 1], WrapAngle((*th)[v]));
  return Status::Ok();
}

// Solves h x = b for a symmetric positive definite sparse h and K right-hand sides; false if h
// is not positive definite.
template <int K>
bool SolveSpd(const Eigen::SparseMatrix<double>& h,
              const Eigen::Matrix<double, Eigen::Dynamic, K>& b,
              Eigen::Matrix<double, Eigen::Dynamic, K>* x) {
#ifdef OMNI_PGM_HAVE_CHOLMOD
  Eigen::SparseMatrix<double> upper = h.triangularView<Eigen::Upper>();
  upper.makeCompressed();
  const int n = static_cast<int>(h.rows());
  cholmod_common c;
  cholmod_start(&c);
  c.print = 0;
  c.nmethods = 1;
  c.method[0].ordering = CHOLMOD_AMD;
  cholmod_sparse a{};
  a.nrow = a.ncol = static_cast<size_t>(n);
  a.nzmax = static_cast<size_t>(upper.nonZeros());
  a.p = upper.outerIndexPtr();
  a.i = upper.innerIndexPtr();
  a.x = upper.valuePtr();
  a.stype = 1;  // the upper triangle holds the matrix
  a.itype = CHOLMOD_INT;
  a.xtype = CHOLMOD_REAL;
  a.dtype = CHOLMOD_DOUBLE;
  a.sorted = 1;
  a.packed = 1;
  cholmod_factor* f = cholmod_analyze(&a, &c);
  bool ok =
      f != nullptr && cholmod_factorize(&a, f, &c) && c.status == CHOLMOD_OK && f->minor == f->n;
  if (ok) {
    cholmod_dense rhs{};
    rhs.nrow = static_cast<size_t>(n);
    rhs.ncol = static_cast<size_t>(b.cols());
    rhs.nzmax = rhs.d = static_cast<size_t>(n);
    rhs.nzmax *= rhs.ncol;
    rhs.x = const_cast<double*>(b.data());
    rhs.xtype = CHOLMOD_REAL;
    rhs.dtype = CHOLMOD_DOUBLE;
    cholmod_dense* sol = cholmod_solve(CHOLMOD_A, f, &rhs, &c);
    ok = sol != nullptr;
    if (ok) {
      *x = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, K>>(
          static_cast<const double*>(sol->x), n, b.cols());
      cholmod_free_dense(&sol, &c);
    }
  }
  if (f != nullptr) cholmod_free_factor(&f, &c);
  cholmod_finish(&c);
  return ok;
#else
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(h);
  if (ldlt.info() != Eigen::Success) return false;
  *x = ldlt.solve(b);
  return true;
#endif
}

// Least squares over 3-vectors x_v (one per vertex, the root's given) with K right-hand sides
// at once: min sum_f ||J_a x_a + J_b x_b - r_f||^2, one 3-row factor f per edge. The normal
// equations are assembled block by block (3x3), so the sparse matrix is the Hessian itself and
// is factorised once for all K columns.
template <int K>
class BlockLeastSquares {
 public:
  using Rhs = Eigen::Matrix<double, 3, K>;
  BlockLeastSquares(int num_vertices, int root, const Rhs& root_value)
      : col_(num_vertices), root_(root), root_value_(root_value) {
    int next = 0;
    for (int v = 0; v < num_vertices; ++v) col_[v] = v == root ? -1 : next++;
    rhs_ = Eigen::Matrix<double, Eigen::Dynamic, K>::Zero(3 * next, K);
    trips_.reserve(9 * static_cast<size_t>(num_vertices));
  }
  void AddFactor(int a, const Eigen::Matrix3d& ja, int b, const Eigen::Matrix3d& jb, const Rhs& r) {
    Rhs target = r;
    if (a == root_) target -= ja * root_value_;
    if (b == root_) target -= jb * root_value_;
    const int ca = col_[a], cb = col_[b];
    if (ca >= 0) {
      AddBlock(ca, ca, ja.transpose() * ja);
      rhs_.template middleRows<3>(3 * ca) += ja.transpose() * target;
    }
    if (cb >= 0) {
      AddBlock(cb, cb, jb.transpose() * jb);
      rhs_.template middleRows<3>(3 * cb) += jb.transpose() * target;
    }
    if (ca >= 0 && cb >= 0) {
      const Eigen::Matrix3d hab = ja.transpose() * jb;
      AddBlock(ca, cb, hab);
      AddBlock(cb, ca, hab.transpose());
    }
  }
  // Every vertex's value, the root's as given.
  Result<std::vector<Rhs>> Solve() {
    const int n = static_cast<int>(rhs_.rows());
    Eigen::SparseMatrix<double> h(n, n);
    h.setFromTriplets(trips_.begin(), trips_.end());
    Eigen::Matrix<double, Eigen::Dynamic, K> x;
    if (!SolveSpd<K>(h, rhs_, &x))
      return MakeError(ErrorCode::kInvalidArgument,
                       "linear initialisation is singular (is the graph connected?)");
    std::vector<Rhs> out(col_.size());
    for (size_t v = 0; v < col_.size(); ++v)
      out[v] = col_[v] < 0 ? root_value_ : Rhs(x.template middleRows<3>(3 * col_[v]));
    return out;
  }

 private:
  void AddBlock(int r, int c, const Eigen::Matrix3d& m) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) trips_.emplace_back(3 * r + i, 3 * c + j, m(i, j));
  }
  std::vector<int> col_;
  int root_;
  Rhs root_value_;
  Eigen::Matrix<double, Eigen::Dynamic, K> rhs_;
  std::vector<Eigen::Triplet<double>> trips_;
};

Eigen::Matrix3d ProjectToSO3(const Eigen::Matrix3d& m) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

Status Chordal3(io::PoseGraph* g, const Topology& t, int root) {
  const int n = static_cast<int>(g->vertices3.size());
  std::vector<int> order, parent;
  if (Status s = Bfs(*g, t, g->vertices3[root].id, &order, &parent); !s.ok()) return s;
  // Rotations, relaxed to any 3x3 matrices: R_b = R_a Z, i.e. R_b^T = Z^T R_a^T. The unknown of
  // vertex v is X_v = R_v^T, whose three columns (the rows of R_v) are three independent
  // problems with the same matrix: one factorisation, three right-hand sides.
  const Eigen::Matrix3d r_root = g->vertices3[root].pose.linear();
  BlockLeastSquares<3> rot(n, root, r_root.transpose());
  for (size_t k = 0; k < g->edges3.size(); ++k) {
    const auto& e = g->edges3[k];
    const auto [a, b] = t.edges[k];
    if (a == b) continue;
    const Eigen::Matrix3d z = e.measurement.linear();
    const double w = std::sqrt(MarginalInfo<6, 3>(e.information, 3).trace() / 3.0);
    rot.AddFactor(a, -w * z.transpose(), b, w * Eigen::Matrix3d::Identity(),
                  Eigen::Matrix3d::Zero());
  }
  auto rv = rot.Solve();
  if (!rv.ok()) return rv.error();
  std::vector<Eigen::Matrix3d> r(n);
  for (int v = 0; v < n; ++v) r[v] = v == root ? r_root : ProjectToSO3((*rv)[v].transpose());
  // Positions: t_b - t_a = R_a t_z, weighted by the rotated marginal translation information.
  BlockLeastSquares<1> pos(n, root, g->vertices3[root].pose.translation());
  for (size_t k = 0; k < g->edges3.size(); ++k) {
    const auto& e = g->edges3[k];
    const auto [a, b] = t.edges[k];
    if (a == b) continue;
    const Eigen::Matrix3d info = r[a] * MarginalInfo<6, 3>(e.information, 0) * r[a].transpose();
    const Eigen::Matrix3d sq = SqrtOf<3>(info);
    pos.AddFactor(a, -sq, b, sq, sq * (r[a] * e.measurement.translation()));
  }
  auto p = pos.Solve();
  if (!p.ok()) return p.error();
  for (int v = 0; v < n; ++v) {
    Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
    x.linear() = r[v];
    x.translation() = (*p)[v];
    g->vertices3[v].pose = x;
  }
  return Status::Ok();
}

}  // namespace

const char* InitializationName(Initialization init) {
  switch (init) {
    case Initialization::kNone:
      return "none";
    case Initialization::kSpanningTree:
      return "spanning-tree";
    case Initialization::kChordal:
      return "chordal";
  }
  return "?";
}

Result<Initialization> ParseInitialization(const std::string& name) {
  if (name == "none") return Initialization::kNone;
  if (name == "spanning-tree") return Initialization::kSpanningTree;
  if (name == "chordal") return Initialization::kChordal;
  return MakeError(ErrorCode::kInvalidArgument,
                   "initialisation '" + name + "' must be one of: none spanning-tree chordal");
}

int ChooseRoot(const io::PoseGraph& g) {
  std::vector<int> ids;
  for (const auto& v : g.vertices2) ids.push_back(v.id);
  for (const auto& v : g.vertices3) ids.push_back(v.id);
  for (int f : g.fixed)
    if (std::find(ids.begin(), ids.end(), f) != ids.end()) return f;
  return ids.empty() ? 0 : *std::min_element(ids.begin(), ids.end());
}

Status InitializeSpanningTree(io::PoseGraph* g, int root_id) {
  const Topology t = BuildTopology(*g);
  std::vector<int> order, parent;
  if (Status s = Bfs(*g, t, root_id, &order, &parent); !s.ok()) return s;
  for (int v : order) {
    const int k = parent[v];
    if (k < 0) continue;
    const auto [a, b] = t.edges[k];
    if (g->is_3d()) {
      const auto& z = g->edges3[k].measurement;
      if (b == v)
        g->vertices3[v].pose = g->vertices3[a].pose * z;
      else
        g->vertices3[v].pose = g->vertices3[b].pose * z.inverse();
    } else {
      const auto& z = g->edges2[k].measurement;
      if (b == v)
        g->vertices2[v].pose = g->vertices2[a].pose * z;
      else
        g->vertices2[v].pose = g->vertices2[b].pose * z.Inverse();
    }
  }
  return Status::Ok();
}

Status InitializeChordal(io::PoseGraph* g, int root_id) {
  const Topology t = BuildTopology(*g);
  auto it = t.index.find(root_id);
  if (it == t.index.end())
    return MakeError(ErrorCode::kInvalidArgument,
                     "root vertex " + std::to_string(root_id) + " is not in the graph");
  return g->is_3d() ? Chordal3(g, t, it->second) : Chordal2(g, t, it->second);
}

Status Initialize(io::PoseGraph* g, Initialization init, int root_id) {
  switch (init) {
    case Initialization::kNone:
      return Status::Ok();
    case Initialization::kSpanningTree:
      return InitializeSpanningTree(g, root_id);
    case Initialization::kChordal:
      return InitializeChordal(g, root_id);
  }
  return Status::Ok();
}

}  // namespace omni::pgm
