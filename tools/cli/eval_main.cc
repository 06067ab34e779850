// omni-eval: trajectory and map error.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "omni/eval/eval.h"
#include "omni/io/grid.h"
#include "omni/io/trajectory_io.h"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni eval ate REF EST [--se3] [--max-dt S] [--json]\n"
      "       omni eval rpe REF EST [--delta N] [--max-dt S] [--json]\n"
      "       omni eval map REF.pgm|yaml EST.pgm|yaml [--no-align] [--max-rotation-deg D]\n"
      "                     [--max-shift-m M] [--tolerance-cells N] [--json]\n"
      "  Trajectories: `index timestamp x y theta` (matched by index) or TUM\n"
      "  `t x y z qx qy qz qw` (matched by time within --max-dt, default 0.02 s).\n"
      "  ATE aligns EST to REF by least squares (SE(2), or SE(3) with --se3).\n"
      "  Map error: SLAMfusion's sqrt(sum (T - M)^2) over cells in {-1, 0, 1}, after a\n"
      "  coarse-to-fine rotation + translation alignment (kept only if its error is lower\n"
      "  than the maps' as they lie); also occupied precision/recall.\n");
}

// The value of `flag` as a number in [lo, hi] (exit 2 otherwise); `integer`: a whole number.
double Num(const char* flag, const char* v, double lo, double hi, bool integer = false) {
  char* end = nullptr;
  const double d = std::strtod(v, &end);
  if (*end != '\0' || !std::isfinite(d) || d < lo || d > hi || (integer && d != std::floor(d))) {
    std::fprintf(stderr, "omni eval: %s '%s' must be %s in [%g, %g]\n", flag, v,
                 integer ? "an integer" : "a number", lo, hi);
    std::exit(2);
  }
  return d;
}

// Reference poses matched by time to a stamp several estimate poses share (Association).
void WarnAmbiguous(size_t ambiguous) {
  if (ambiguous == 0) return;
  std::fprintf(stderr,
               "omni eval: warning: %zu reference poses matched by time a stamp that several "
               "estimate poses share; which one is meant is a guess (the indexed form, `index "
               "timestamp x y theta`, matches exactly)\n",
               ambiguous);
}

// A trajectory that covers only part of the reference is scored on that part alone: said, so
// that a run that stopped early does not pass for a good one.
void WarnCoverage(size_t matched, size_t reference) {
  if (matched < reference)
    std::fprintf(stderr,
                 "omni eval: warning: the estimate matches %zu of the reference's %zu poses; "
                 "the other %zu are not scored\n",
                 matched, reference, reference - matched);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && (!std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h"))) {
    Usage(stdout);
    return 0;
  }
  if (argc < 4) {
    Usage(stderr);
    return 2;
  }
  const std::string mode = argv[1], ref_path = argv[2], est_path = argv[3];
  bool se3 = false, json = false;
  double max_dt = 0.02;
  int delta = 1;
  omni::eval::MapCompareOptions mopt;
  for (int i = 4; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&]() -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "omni eval: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--se3")
      se3 = true;
    else if (a == "--json")
      json = true;
    else if (a == "--max-dt")
      max_dt = Num("--max-dt", val(), 0.0, 3600.0);
    else if (a == "--delta")
      delta = static_cast<int>(Num("--delta", val(), 1, 1e6, true));
    else if (a == "--no-align")
      mopt.align = false;
    else if (a == "--max-rotation-deg")
      mopt.max_rotation_rad = Num("--max-rotation-deg", val(), 0.0, 180.0) * M_PI / 180;
    else if (a == "--max-shift-m")
      mopt.max_shift_m = Num("--max-shift-m", val(), 0.0, 1000.0);
    else if (a == "--tolerance-cells")
      mopt.match_tolerance_cells = static_cast<int>(Num("--tolerance-cells", val(), 0, 100, true));
    else {
      std::fprintf(stderr, "omni eval: unknown option '%s'\n", a.c_str());
      Usage(stderr);
      return 2;
    }
  }
  if (mode == "ate" || mode == "rpe") {
    auto ref = omni::io::ReadTrajectory(ref_path);
    auto est = omni::io::ReadTrajectory(est_path);
    if (!ref.ok() || !est.ok()) {
      std::fprintf(stderr, "omni eval: %s\n",
                   (!ref.ok() ? ref.error() : est.error()).message.c_str());
      return 1;
    }
    if (mode == "ate") {
      auto r = omni::eval::ComputeAte(*ref, *est, se3, max_dt);
      if (!r.ok()) {
        std::fprintf(stderr, "omni eval: %s\n", r.error().message.c_str());
        return 1;
      }
      WarnAmbiguous(r->ambiguous);
      WarnCoverage(r->matched, r->reference_poses);
      if (json)
        std::printf(
            "{\"metric\": \"ate\", \"matched\": %zu, \"reference_poses\": %zu, "
            "\"ate_rmse_m\": %.6f, \"ate_mean_m\": %.6f, \"ate_max_m\": %.6f, "
            "\"rot_rmse_rad\": %.6f}\n",
            r->matched, r->reference_poses, r->rmse_m, r->mean_m, r->max_m, r->rot_rmse_rad);
      else
        std::printf(
            "ATE (%s alignment) over %zu matched poses: RMSE %.4f m, mean %.4f m, max %.4f m, "
            "rotation RMSE %.4f rad\n",
            se3 ? "SE(3)" : "SE(2)", r->matched, r->rmse_m, r->mean_m, r->max_m, r->rot_rmse_rad);
    } else {
      auto r = omni::eval::ComputeRpe(*ref, *est, delta, max_dt);
      if (!r.ok()) {
        std::fprintf(stderr, "omni eval: %s\n", r.error().message.c_str());
        return 1;
      }
      WarnAmbiguous(r->ambiguous);
      WarnCoverage(r->matched, r->reference_poses);
      if (json)
        std::printf(
            "{\"metric\": \"rpe\", \"pairs\": %zu, \"rpe_trans_rmse_m\": %.6f, "
            "\"rpe_trans_max_m\": %.6f, "
            "\"rpe_rot_rmse_rad\": %.6f, \"rpe_rot_max_rad\": %.6f}\n",
            r->pairs, r->trans_rmse_m, r->trans_max_m, r->rot_rmse_rad, r->rot_max_rad);
      else
        std::printf(
            "RPE (delta %d) over %zu pairs: translation RMSE %.4f m (max %.4f), rotation RMSE %.4f "
            "rad (max %.4f)\n",
            delta, r->pairs, r->trans_rmse_m, r->trans_max_m, r->rot_rmse_rad, r->rot_max_rad);
    }
    return 0;
  }
  if (mode == "map") {
    // A bare image has no cell size or origin: say what is assumed (the comparison scales and
    // aligns by them).
    for (const std::string& p : {ref_path, est_path})
      if (p.size() < 5 || (p.compare(p.size() - 5, 5, ".yaml") != 0 &&
                           (p.size() < 4 || p.compare(p.size() - 4, 4, ".yml") != 0)))
        std::fprintf(stderr,
                     "omni eval: warning: %s is an image without its map_server YAML: 0.05 m "
                     "cells and origin (0, 0) assumed; give the .yaml for its own\n",
                     p.c_str());
    auto ref = omni::io::ReadMapServer(ref_path);
    auto est = omni::io::ReadMapServer(est_path);
    if (!ref.ok() || !est.ok()) {
      std::fprintf(stderr, "omni eval: %s\n",
                   (!ref.ok() ? ref.error() : est.error()).message.c_str());
      return 1;
    }
    const auto r = omni::eval::CompareMaps(*ref, *est, mopt);
    if (json)
      std::printf(
          "{\"metric\": \"map\", \"map_error\": %.4f, \"cells\": %zu, \"differing_cells\": %zu, "
          "\"precision\": %.4f, \"recall\": %.4f, \"dx_m\": %.4f, \"dy_m\": %.4f, "
          "\"rotation_rad\": %.5f}\n",
          r.error, r.cells, r.differing_cells, r.precision, r.recall, r.dx_m, r.dy_m,
          r.rotation_rad);
    else
      std::printf(
          "map error %.3f over %zu cells (%zu differ); occupied precision %.3f, recall %.3f; "
          "alignment dx %.3f m, dy %.3f m, rotation %.4f rad\n",
          r.error, r.cells, r.differing_cells, r.precision, r.recall, r.dx_m, r.dy_m,
          r.rotation_rad);
    return 0;
  }
  std::fprintf(stderr, "omni eval: unknown mode '%s'\n", mode.c_str());
  Usage(stderr);
  return 2;
}
