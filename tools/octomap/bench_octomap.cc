// omni-bench-octomap: our parallel key-set insertion beside OctoMap's own insertPointCloud,
// same frames, same resolution and range, same run. Prints a table and writes
// out/bench/octomap.jsonl (one row per dataset and resolution).
#include <bzlib.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "omni/octomap_builder/depth_io.h"
#include "omni/octomap_builder/depth_points.h"
#include "omni/octomap_builder/key_set_inserter.h"
#include "omni/octomap_builder/tree_compare.h"

namespace fs = std::filesystem;
using omni::octo::DepthImage;
using omni::octo::DepthIntrinsics;

namespace {

struct Frame {
  std::vector<Eigen::Vector3f> points;  // map frame
  Eigen::Vector3f origin;
};

struct Dataset {
  std::string name;
  std::vector<Frame> frames;
  size_t pixels_per_frame = 0;
};

int64_t NowUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

bool LoadRgbd(const std::string& dir, const std::string& ext, const DepthIntrinsics& k,
              double max_depth_m, Dataset* out, std::string* err) {
  auto poses = omni::octo::ReadPoseFile(dir + "/pose.txt");
  if (!poses.ok()) {
    *err = poses.error().message;
    return false;
  }
  omni::octo::DepthToPointsOptions opt;
  opt.min_depth_m = 0.05;
  opt.max_depth_m = max_depth_m;
  for (size_t i = 0; i < poses->size(); ++i) {
    DepthImage im;
    const std::string path = dir + "/depth/" + std::to_string(i + 1) + ext;
    omni::Status s = omni::octo::ReadDepthFile(path, &im);
    if (!s.ok()) {
      *err = s.message();
      return false;
    }
    im.intrinsics = k;
    auto pts = omni::octo::DepthToPoints(im, opt);
    if (!pts.ok()) {
      *err = pts.error().message;
      return false;
    }
    const Eigen::Isometry3f t = (*poses)[i].cast<float>();
    Frame f;
    f.points.reserve(pts->size());
    for (const auto& p : *pts) f.points.push_back(t * p);
    f.origin = t.translation();
    out->pixels_per_frame = static_cast<size_t>(im.width) * im.height;
    out->frames.push_back(std::move(f));
  }
  return true;
}

bool LoadScanDat(const std::string& path, Dataset* out, std::string* err) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) {
    *err = "cannot open " + path;
    return false;
  }
  int bzerr = BZ_OK;
  BZFILE* bz = BZ2_bzReadOpen(&bzerr, f, 0, 0, nullptr, 0);
  std::string text;
  char buf[1 << 16];
  while (bzerr == BZ_OK) {
    const int n = BZ2_bzRead(&bzerr, bz, buf, sizeof(buf));
    if (n > 0) text.append(buf, static_cast<size_t>(n));
  }
  BZ2_bzReadClose(&bzerr, bz);
  std::fclose(f);
  std::istringstream in(text);
  Frame fr;
  fr.origin = Eigen::Vector3f::Zero();  // one scan taken at the origin
  float x, y, z;
  while (in >> x >> y >> z) fr.points.emplace_back(x, y, z);
  if (fr.points.empty()) {
    *err = path + ": no points";
    return false;
  }
  out->pixels_per_frame = fr.points.size();
  out->frames.push_back(std::move(fr));
  return true;
}

void Usage() {
  std::cout << "usage: omni-bench-octomap [--datasets DIR] [--out FILE] [--threads N]\n"
               "         [--resolutions 0.01,0.05] [--max-range M] [--only NAME]\n"
               "         [--subvoxel N] [--max-bitmap-bytes B]\n"
               "Times OctoMap's OcTree::insertPointCloud (discretize off and on) and omni's\n"
               "parallel key-set insertion (subvoxel N=2: the builder's default; discretize;\n"
               "exact) on\n"
               "the same frames in the same run (rgbd/iclnuim-5frames, rgbd/kinect-5frames with\n"
               "their given poses, octomap/scan.dat.bz2 from the origin), at the same resolution\n"
               "and max range (default 5 m). Reports points/s, ms/frame, speedups and the IoU of\n"
               "the occupied voxels against plain insertPointCloud; writes one JSON row per\n"
               "dataset and resolution (default out/bench/octomap.jsonl).\n";
}

}  // namespace

int main(int argc, char** argv) {
  std::string datasets = "../shared/datasets";
  std::string out_path = "out/bench/octomap.jsonl";
  std::string only;
  int threads = 2;
  int subvoxel = 2;
  size_t max_bitmap_bytes = omni::octo::KeySetOptions().max_bitmap_bytes;
  double max_range = 5.0;
  std::vector<double> resolutions{0.01, 0.05};
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << a << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") {
      Usage();
      return 0;
    } else if (a == "--datasets") {
      datasets = next();
    } else if (a == "--out") {
      out_path = next();
    } else if (a == "--threads") {
      threads = std::stoi(next());
    } else if (a == "--max-range") {
      max_range = std::stod(next());
    } else if (a == "--subvoxel") {
      subvoxel = std::stoi(next());
    } else if (a == "--max-bitmap-bytes") {  // 0: the hash-set key sets (for comparison)
      max_bitmap_bytes = std::stoull(next());
    } else if (a == "--only") {
      only = next();
    } else if (a == "--resolutions") {
      resolutions.clear();
      std::stringstream s(next());
      std::string tok;
      while (std::getline(s, tok, ',')) resolutions.push_back(std::stod(tok));
    } else {
      std::cerr << "unknown option " << a << "\n";
      Usage();
      return 2;
    }
  }

  std::vector<Dataset> sets;
  auto add = [&](const std::string& name, auto&& loader) {
    if (!only.empty() && name != only) return;
    Dataset d;
    d.name = name;
    std::string err;
    if (!loader(&d, &err)) {
      std::cerr << "skipping " << name << ": " << err << "\n";
      return;
    }
    sets.push_back(std::move(d));
  };
  add("iclnuim-5frames", [&](Dataset* d, std::string* e) {
    return LoadRgbd(datasets + "/rgbd/iclnuim-5frames", ".png", {481.2, -480.0, 319.5, 239.5, 5000},
                    max_range + 2, d, e);
  });
  add("kinect-5frames", [&](Dataset* d, std::string* e) {
    return LoadRgbd(datasets + "/rgbd/kinect-5frames", ".pgm", {518.0, 519.0, 325.5, 253.5, 1000},
                    max_range + 2, d, e);
  });
  add("scan.dat", [&](Dataset* d, std::string* e) {
    return LoadScanDat(datasets + "/octomap/scan.dat.bz2", d, e);
  });
  if (sets.empty()) {
    std::cerr << "no dataset found under " << datasets << "\n";
    return 1;
  }

  fs::create_directories(fs::path(out_path).parent_path());
  std::ofstream jsonl(out_path);
  if (!jsonl) {
    std::cerr << "cannot write " << out_path << "\n";
    return 1;
  }
  std::printf("%-16s %5s %6s %8s | %10s %9s | %10s %9s %7s %7s | %10s %9s %7s | %10s %9s %7s\n", "",
              "", "", "", "octomap", "", "omni", "(subvox", "default)", "", "omni", "exact", "",
              "octomap", "discret.", "");
  std::printf("%-16s %5s %6s %8s | %10s %9s | %10s %9s %7s %7s | %10s %9s %7s | %10s %9s %7s\n",
              "dataset", "res_m", "frames", "points", "points/s", "ms/frame", "points/s",
              "ms/frame", "speedup", "iou", "points/s", "ms/frame", "speedup", "points/s",
              "ms/frame", "iou");
  for (const Dataset& d : sets) {
    size_t points = 0;
    for (const auto& f : d.frames) points += f.points.size();
    const double nf = static_cast<double>(d.frames.size());
    for (double res : resolutions) {
      // Each run builds its tree from scratch over all frames; the trees are kept for the IoU.
      struct Run {
        double seconds = 0;
        std::unique_ptr<octomap::OcTree> tree;
        int64_t rays_us = 0, merge_us = 0, update_us = 0;
      };
      auto run_plain = [&](bool disc) {
        Run r;
        r.tree = std::make_unique<octomap::OcTree>(res);
        const int64_t t0 = NowUs();
        for (const auto& f : d.frames) {
          octomap::Pointcloud pc;
          pc.reserve(f.points.size());
          for (const auto& p : f.points) pc.push_back(p.x(), p.y(), p.z());
          r.tree->insertPointCloud(pc, octomap::point3d(f.origin.x(), f.origin.y(), f.origin.z()),
                                   max_range, false, disc);
        }
        r.seconds = (NowUs() - t0) * 1e-6;
        return r;
      };
      enum class Mode { kExact, kDiscretize, kSubvoxel };
      auto run_omni = [&](Mode mode) {
        Run r;
        r.tree = std::make_unique<octomap::OcTree>(res);
        omni::octo::KeySetOptions ko;
        ko.num_threads = threads;
        ko.max_range_m = max_range;
        ko.discretize = mode == Mode::kDiscretize;
        ko.subvoxel = mode == Mode::kSubvoxel ? subvoxel : 0;
        ko.max_bitmap_bytes = max_bitmap_bytes;
        omni::octo::ParallelKeySetInserter inserter(res, ko);
        const int64_t t0 = NowUs();
        for (const auto& f : d.frames) {
          const auto st = inserter.Insert(r.tree.get(), f.points, f.origin);
          r.rays_us += st.rays_us;
          r.merge_us += st.merge_us + st.sort_us;
          r.update_us += st.update_us;
        }
        r.seconds = (NowUs() - t0) * 1e-6;
        return r;
      };
      const Run plain = run_plain(false);
      const Run plain_d = run_plain(true);
      const Run omni_s = run_omni(Mode::kSubvoxel);
      const Run omni_d = run_omni(Mode::kDiscretize);
      const Run omni_x = run_omni(Mode::kExact);
      const auto iou_s = omni::octo::CompareOccupied(*omni_s.tree, *plain.tree);
      const auto iou_d = omni::octo::CompareOccupied(*omni_d.tree, *plain.tree);
      const auto iou_pd = omni::octo::CompareOccupied(*plain_d.tree, *plain.tree);
      const auto iou_x = omni::octo::CompareOccupied(*omni_x.tree, *plain.tree);
      const bool same_x = omni::octo::SameLeaves(*omni_x.tree, *plain.tree);
      const bool same_d = omni::octo::SameLeaves(*omni_d.tree, *plain_d.tree);
      auto pps = [&](const Run& r) { return points / r.seconds; };
      auto msf = [&](const Run& r) { return r.seconds * 1e3 / nf; };
      std::printf(
          "%-16s %5.2f %6zu %8zu | %10.0f %9.1f | %10.0f %9.1f %6.2fx %7.4f | %10.0f %9.1f %6.2fx "
          "| "
          "%10.0f %9.1f %7.4f\n",
          d.name.c_str(), res, d.frames.size(), points, pps(plain), msf(plain), pps(omni_s),
          msf(omni_s), plain.seconds / omni_s.seconds, iou_s.iou, pps(omni_x), msf(omni_x),
          plain.seconds / omni_x.seconds, pps(plain_d), msf(plain_d), iou_pd.iou);
      std::printf(
          "%-16s   omni exact: IoU %.4f, same leaves as octomap: %s | omni discretize: %.1f "
          "ms/frame, %.2fx octomap discretize, same leaves as it: %s, IoU vs plain %.4f\n",
          "", iou_x.iou, same_x ? "yes" : "NO", msf(omni_d), plain_d.seconds / omni_d.seconds,
          same_d ? "yes" : "NO", iou_d.iou);
      std::printf("%-16s   omni per frame: rays %.1f ms, merge+sort %.1f ms, tree update %.1f ms\n",
                  "", omni_s.rays_us * 1e-3 / nf, omni_s.merge_us * 1e-3 / nf,
                  omni_s.update_us * 1e-3 / nf);
      std::fflush(stdout);
      jsonl << std::setprecision(6) << "{\"system\":\"omni_vs_octomap\",\"dataset\":\"" << d.name
            << "\",\"resolution_m\":" << res << ",\"max_range_m\":" << max_range
            << ",\"frames\":" << d.frames.size() << ",\"points\":" << points
            << ",\"threads\":" << threads << ",\"omni_mode\":\"subvoxel" << subvoxel << "\""
            << ",\"omni_points_per_s\":" << pps(omni_s)
            << ",\"octomap_points_per_s\":" << pps(plain)
            << ",\"speedup\":" << plain.seconds / omni_s.seconds << ",\"iou\":" << iou_s.iou
            << ",\"omni_ms_per_frame\":" << msf(omni_s)
            << ",\"octomap_ms_per_frame\":" << msf(plain)
            << ",\"omni_exact_points_per_s\":" << pps(omni_x)
            << ",\"omni_exact_ms_per_frame\":" << msf(omni_x)
            << ",\"omni_exact_speedup\":" << plain.seconds / omni_x.seconds
            << ",\"omni_exact_iou\":" << iou_x.iou
            << ",\"omni_exact_same_leaves\":" << (same_x ? "true" : "false")
            << ",\"octomap_discretize_points_per_s\":" << pps(plain_d)
            << ",\"octomap_discretize_ms_per_frame\":" << msf(plain_d)
            << ",\"octomap_discretize_iou\":" << iou_pd.iou
            << ",\"omni_discretize_ms_per_frame\":" << msf(omni_d)
            << ",\"omni_discretize_speedup_vs_octomap_discretize\":"
            << plain_d.seconds / omni_d.seconds
            << ",\"omni_discretize_same_leaves_as_octomap_discretize\":"
            << (same_d ? "true" : "false") << ",\"omni_discretize_iou\":" << iou_d.iou
            << ",\"omni_rays_ms_per_frame\":" << omni_s.rays_us * 1e-3 / nf
            << ",\"omni_merge_ms_per_frame\":" << omni_s.merge_us * 1e-3 / nf
            << ",\"omni_update_ms_per_frame\":" << omni_s.update_us * 1e-3 / nf
            << ",\"occupied_voxels_octomap\":" << iou_s.occupied_b
            << ",\"occupied_voxels_omni\":" << iou_s.occupied_a << "}\n";
      jsonl.flush();
    }
  }
  std::printf("wrote %s\n", out_path.c_str());
  return 0;
}
