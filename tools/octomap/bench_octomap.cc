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
               "Times OctoMap's OcTree::insertPointCloud and omni's parallel key-set insertion\n"
               "on the same frames (rgbd/iclnuim-5frames, rgbd/kinect-5frames,\n"
               "octomap/scan.dat.bz2), reports points/s, ms/frame, speedup and the IoU of the\n"
               "occupied leaves, and writes one JSON row per dataset and resolution.\n";
}

}  // namespace

int main(int argc, char** argv) {
  std::string datasets = "../shared/datasets";
  std::string out_path = "out/bench/octomap.jsonl";
  std::string only;
  int threads = 2;
  bool discretize = false;
  double max_range = 8.0;
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
    } else if (a == "--discretize") {
      discretize = true;
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
  std::printf("%-16s %6s %6s %9s | %12s %9s | %12s %9s | %7s %7s | %8s\n", "dataset", "res_m",
              "frames", "points", "octomap pt/s", "ms/frame", "omni pt/s", "ms/frame", "speedup",
              "iou", "leaves");
  for (const Dataset& d : sets) {
    size_t points = 0;
    for (const auto& f : d.frames) points += f.points.size();
    for (double res : resolutions) {
      octomap::OcTree plain(res);
      const int64_t t0 = NowUs();
      for (const auto& f : d.frames) {
        octomap::Pointcloud pc;
        pc.reserve(f.points.size());
        for (const auto& p : f.points) pc.push_back(p.x(), p.y(), p.z());
        plain.insertPointCloud(pc, octomap::point3d(f.origin.x(), f.origin.y(), f.origin.z()),
                               max_range, false, false);
      }
      const double plain_s = (NowUs() - t0) * 1e-6;

      omni::octo::KeySetOptions ko;
      ko.num_threads = threads;
      ko.max_range_m = max_range;
      ko.discretize = discretize;
      omni::octo::ParallelKeySetInserter inserter(res, ko);
      octomap::OcTree ours(res);
      int64_t keys_us = 0, update_us = 0, rays_us = 0, merge_us = 0, sort_us = 0;
      size_t free_keys = 0;
      const int64_t t1 = NowUs();
      for (const auto& f : d.frames) {
        const auto st = inserter.Insert(&ours, f.points, f.origin);
        keys_us += st.keys_us;
        update_us += st.update_us;
        rays_us += st.rays_us;
        merge_us += st.merge_us;
        sort_us += st.sort_us;
        free_keys += st.free_keys;
      }
      const double ours_s = (NowUs() - t1) * 1e-6;
      const auto cmp = omni::octo::CompareOccupied(ours, plain);
      const double nf = static_cast<double>(d.frames.size());
      const double plain_pps = points / plain_s, ours_pps = points / ours_s;
      std::printf("%-16s %6.2f %6zu %9zu | %12.0f %9.1f | %12.0f %9.1f | %7.2f %7.4f | %8zu\n",
                  d.name.c_str(), res, d.frames.size(), points, plain_pps, plain_s * 1e3 / nf,
                  ours_pps, ours_s * 1e3 / nf, plain_s / ours_s, cmp.iou, cmp.occupied_b);
      std::fprintf(
          stderr,
          "  omni phases per frame: rays %.1f ms, merge+sort %.1f ms, join %.1f ms, update %.1f "
          "ms; %.0f free keys\n",
          rays_us * 1e-3 / nf, merge_us * 1e-3 / nf, sort_us * 1e-3 / nf, update_us * 1e-3 / nf,
          free_keys / nf);
      std::fflush(stdout);
      jsonl << std::setprecision(6) << "{\"system\":\"omni_vs_octomap\",\"dataset\":\"" << d.name
            << "\",\"resolution_m\":" << res << ",\"max_range_m\":" << max_range
            << ",\"frames\":" << d.frames.size() << ",\"points\":" << points
            << ",\"threads\":" << threads << ",\"omni_points_per_s\":" << ours_pps
            << ",\"octomap_points_per_s\":" << plain_pps << ",\"speedup\":" << plain_s / ours_s
            << ",\"iou\":" << cmp.iou << ",\"omni_ms_per_frame\":" << ours_s * 1e3 / nf
            << ",\"octomap_ms_per_frame\":" << plain_s * 1e3 / nf
            << ",\"omni_keys_ms_per_frame\":" << keys_us * 1e-3 / nf
            << ",\"omni_update_ms_per_frame\":" << update_us * 1e-3 / nf
            << ",\"occupied_voxels_omni\":" << cmp.occupied_a
            << ",\"occupied_voxels_octomap\":" << cmp.occupied_b << "}\n";
    }
  }
  std::printf("wrote %s\n", out_path.c_str());
  return 0;
}
