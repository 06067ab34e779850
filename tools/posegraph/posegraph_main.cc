// omni-posegraph (./omni posegraph ...): batch optimisation of a g2o / TORO pose graph with the
// pose_graph_mapper's Ceres back end, and chi^2 of any graph file with our evaluator.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "omni/io/g2o.h"
#include "omni/pose_graph_mapper/batch_optimizer.h"
#include "omni/pose_graph_mapper/chi2.h"

namespace {

void Usage(FILE* f) {
  std::fprintf(
      f,
      "usage: omni posegraph optimize IN.g2o [-o OUT.g2o] [--config FILE] [--init NAME]\n"
      "                               [--max-iterations N] [--loss none|huber|cauchy]\n"
      "                               [--threads N] [--trust-region R]\n"
      "                               [--sparse suitesparse|eigen]\n"
      "                               [--verbose] [--json]\n"
      "       omni posegraph chi2 GRAPH.g2o [--poses RESULT.g2o] [--json]\n"
      "\n"
      "  optimize  Optimises a 2D (VERTEX_SE2/EDGE_SE2, TORO VERTEX2/EDGE2) or 3D\n"
      "            (VERTEX_SE3:QUAT/EDGE_SE3:QUAT) graph: initialisation (--init none |\n"
      "            spanning-tree | chordal, default from config, chordal), then Ceres\n"
      "            Levenberg-Marquardt with sparse Cholesky on all cores. Prints chi^2 =\n"
      "            sum e^T Omega e (g2o's edge errors) of the input, after initialisation\n"
      "            and after optimisation, the iterations and the times; -o writes the\n"
      "            optimised graph as g2o. Edge-only files (CSAIL.g2o) get a spanning tree.\n"
      "  chi2      chi^2 of GRAPH's edges at GRAPH's vertex poses, or at the vertex poses of\n"
      "            RESULT (any system's output; its edges are ignored, every vertex of GRAPH\n"
      "            must be in RESULT). This is how ./omni bench posegraph scores every system.\n"
      "\n"
      "  --config FILE  YAML options (default config/pose_graph_mapper.yaml when present;\n"
      "                 command-line options override it)\n"
      "  --sparse suitesparse|eigen  sparse Cholesky library (Ceres)\n"
      "  --trust-region R  Levenberg-Marquardt's initial trust-region radius\n"
      "  --verbose      Ceres' full report (stage times) on stderr\n"
      "  --json         one JSON object on stdout instead of the text report\n"
      "Errors (unreadable file, an edge to a missing vertex, an information matrix that is\n"
      "not positive definite) name the file and line and exit non-zero.\n");
}

int Fail(const std::string& msg) {
  std::fprintf(stderr, "omni posegraph: %s\n", msg.c_str());
  return 1;
}

bool ParseInt(const char* s, int* out) {
  char* end = nullptr;
  const long v = std::strtol(s, &end, 10);
  if (end == s || *end != '\0' || v < 1 || v > 1000000) return false;
  *out = static_cast<int>(v);
  return true;
}

int CmdChi2(int argc, char** argv) {
  std::string graph_path, poses_path;
  bool json = false;
  for (int i = 0; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--poses" && i + 1 < argc) {
      poses_path = argv[++i];
    } else if (a == "--json") {
      json = true;
    } else if (!a.empty() && a[0] == '-') {
      return Fail("chi2: unknown option '" + a + "' (see --help)");
    } else if (graph_path.empty()) {
      graph_path = a;
    } else {
      return Fail("chi2: unexpected argument '" + a + "'");
    }
  }
  if (graph_path.empty()) return Fail("chi2: which graph? (see --help)");
  auto g = omni::io::ReadPoseGraph(graph_path);
  if (!g.ok()) return Fail(g.error().message);
  if (!poses_path.empty()) {
    auto p = omni::io::ReadPoseGraph(poses_path);
    if (!p.ok()) return Fail(p.error().message);
    if (p->vertices2.empty() && p->vertices3.empty())
      return Fail(poses_path + ": no vertices (--poses takes a g2o file with the poses to score)");
    g->vertices2 = p->vertices2;
    g->vertices3 = p->vertices3;
  }
  auto chi2 = omni::pgm::ComputeChi2(*g);
  if (!chi2.ok())  // the edges (and their line numbers) are the graph's; the poses may be another's
    return Fail(graph_path + ": " + chi2.error().message +
                (poses_path.empty() ? "" : " (poses from " + poses_path + ")"));
  if (json)
    std::printf("{\"graph\": \"%s\", \"chi2\": %.10g}\n", graph_path.c_str(), *chi2);
  else
    std::printf("chi2 %.10g\n", *chi2);
  return 0;
}

int CmdOptimize(int argc, char** argv) {
  std::string in, out, config, init, loss, sparse;
  int max_iter = 0, threads = 0;
  bool json = false, verbose = false;
  double radius = 0;
  for (int i = 0; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> const char* { return i + 1 < argc ? argv[++i] : nullptr; };
    if (a == "-o" || a == "--out") {
      const char* v = next();
      if (!v) return Fail("optimize: -o needs a file");
      out = v;
    } else if (a == "--config") {
      const char* v = next();
      if (!v) return Fail("optimize: --config needs a file");
      config = v;
    } else if (a == "--init") {
      const char* v = next();
      if (!v) return Fail("optimize: --init needs a name");
      init = v;
    } else if (a == "--loss") {
      const char* v = next();
      if (!v) return Fail("optimize: --loss needs a name");
      loss = v;
    } else if (a == "--max-iterations") {
      const char* v = next();
      if (!v || !ParseInt(v, &max_iter))
        return Fail("optimize: --max-iterations needs an integer in [1, 1000000]");
    } else if (a == "--threads") {
      const char* v = next();
      if (!v || !ParseInt(v, &threads))
        return Fail("optimize: --threads needs an integer in [1, 1000000]");
    } else if (a == "--json") {
      json = true;
    } else if (a == "--sparse") {
      const char* v = next();
      if (!v) return Fail("optimize: --sparse needs suitesparse or eigen");
      sparse = v;
    } else if (a == "--verbose") {
      verbose = true;
    } else if (a == "--trust-region") {
      const char* v = next();
      radius = v ? std::atof(v) : 0;
      if (!(radius > 0)) return Fail("optimize: --trust-region needs a number > 0");
    } else if (!a.empty() && a[0] == '-') {
      return Fail("optimize: unknown option '" + a + "' (see --help)");
    } else if (in.empty()) {
      in = a;
    } else {
      return Fail("optimize: unexpected argument '" + a + "'");
    }
  }
  if (in.empty()) return Fail("optimize: which graph? (see --help)");

  omni::pgm::BatchOptions opt;
  if (config.empty()) {
    const char* def = "config/pose_graph_mapper.yaml";
    if (FILE* f = std::fopen(def, "r")) {
      std::fclose(f);
      config = def;
    }
  }
  if (!config.empty()) {
    auto o = omni::pgm::LoadBatchOptionsFile(config);
    if (!o.ok()) return Fail("bad config:\n" + o.error().message);
    opt = *o;
  }
  if (!init.empty()) {
    auto p = omni::pgm::ParseInitialization(init);
    if (!p.ok()) return Fail("optimize: --init: " + p.error().message);
    opt.initialization = *p;
  }
  if (!loss.empty()) opt.loss = loss;
  if (!sparse.empty()) opt.sparse_library = sparse;
  if (max_iter > 0) opt.max_iterations = max_iter;
  if (radius > 0) opt.initial_trust_region_radius = radius;
  opt.num_threads =
      threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));

  using Clock = std::chrono::steady_clock;
  auto seconds = [](Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
  };
  // A bad option is the command line's mistake, not the graph's: said before reading it.
  if (omni::Status s = opt.Validate(); !s.ok()) return Fail("optimize: " + s.message());
  const auto t_read = Clock::now();
  auto g = omni::io::ReadPoseGraph(in);
  if (!g.ok()) return Fail(g.error().message);
  const double read_s = seconds(t_read);
  auto r = omni::pgm::OptimizeGraph(&*g, opt);
  if (!r.ok()) return Fail(in + ": " + r.error().message);
  if (verbose) std::fprintf(stderr, "%s\n", r->ceres_report.c_str());
  double write_s = 0;
  if (!out.empty()) {
    const auto t_write = Clock::now();
    // Its folder is made as a recorder would (`-o out/x.g2o` on a fresh checkout).
    std::error_code ec;
    if (const auto dir = std::filesystem::path(out).parent_path(); !dir.empty())
      std::filesystem::create_directories(dir, ec);
    if (omni::Status s = omni::io::WriteG2o(out, *g); !s.ok()) return Fail(s.message());
    write_s = seconds(t_write);
  }
  const size_t nv = g->is_3d() ? g->vertices3.size() : g->vertices2.size();
  const size_t ne = g->is_3d() ? g->edges3.size() : g->edges2.size();
  if (json) {
    std::printf(
        "{\"graph\": \"%s\", \"type\": \"%s\", \"vertices\": %zu, \"edges\": %zu, "
        "\"initialization\": \"%s\", \"chi2_before\": %.10g, \"chi2_initialized\": %.10g, "
        "\"chi2\": %.10g, \"iterations\": %d, \"read_s\": %.6f, \"init_s\": %.6f, "
        "\"solve_s\": %.6f, \"write_s\": %.6f, \"termination\": \"%s\"}\n",
        in.c_str(), g->is_3d() ? "SE3" : "SE2", nv, ne,
        omni::pgm::InitializationName(opt.initialization), r->chi2_input, r->chi2_initialized,
        r->chi2_final, r->iterations, read_s, r->init_s, r->solve_s, write_s,
        r->termination.c_str());
  } else {
    std::printf("graph            %s (%s, %zu vertices, %zu edges%s)\n", in.c_str(),
                g->is_3d() ? "SE3" : "SE2", nv, ne, g->vertices_implicit ? ", implicit" : "");
    std::printf("chi2 before      %.6g (the file's poses)\n", r->chi2_input);
    std::printf("chi2 initialised %.6g (%s, %.3f s)\n", r->chi2_initialized,
                omni::pgm::InitializationName(opt.initialization), r->init_s);
    std::printf("chi2 after       %.6g\n", r->chi2_final);
    std::printf("iterations       %d (%s)\n", r->iterations, r->termination.c_str());
    std::printf("time             %.3f s (initialisation %.3f s, Ceres %.3f s, %d threads)\n",
                r->init_s + r->solve_s, r->init_s, r->solve_s, opt.num_threads);
    std::printf("read, write      %.3f s, %.3f s\n", read_s, write_s);
    if (!out.empty()) std::printf("wrote            %s\n", out.c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    Usage(stderr);
    return 2;
  }
  const std::string cmd = argv[1];
  if (cmd == "-h" || cmd == "--help" || cmd == "help") {
    Usage(stdout);
    return 0;
  }
  for (int i = 2; i < argc; ++i)
    if (!std::strcmp(argv[i], "-h") || !std::strcmp(argv[i], "--help")) {
      Usage(stdout);
      return 0;
    }
  if (cmd == "optimize") return CmdOptimize(argc - 2, argv + 2);
  if (cmd == "chi2") return CmdChi2(argc - 2, argv + 2);
  Usage(stderr);
  return Fail("unknown subcommand '" + cmd + "'");
}
