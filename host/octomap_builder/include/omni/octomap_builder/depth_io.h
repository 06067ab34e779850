// Files of the offline path: 16-bit depth images (PNG, binary PGM), pose lists, 8-bit images,
// PCD point clouds. Everything returns Status/Result naming the file.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/common/result.h"
#include "omni/octomap_builder/depth_points.h"

namespace omni::octo {

// Reads a 16-bit greyscale PNG (or an 8-bit one, widened) into image->data/width/height.
Status ReadDepthPng(const std::string& path, DepthImage* image);
// Reads a binary PGM (P5); maxval > 255 means 16-bit big-endian samples.
Status ReadDepthPgm(const std::string& path, DepthImage* image);
// By extension: .png or .pgm.
Status ReadDepthFile(const std::string& path, DepthImage* image);

// Lines "tx ty tz qx qy qz qw" (camera to world); blank lines and '#' comments skipped.
Result<std::vector<Eigen::Isometry3d>> ReadPoseFile(const std::string& path);

// 8-bit images. Rows top to bottom; `channels` 1 (grey) or 3 (RGB).
Status WritePng8(const std::string& path, int width, int height, int channels,
                 const std::vector<uint8_t>& pixels);
Status WritePgm8(const std::string& path, int width, int height,
                 const std::vector<uint8_t>& pixels);

// Point cloud as PCD v0.7 (fields x y z, float), binary or ASCII.
Status WritePcd(const std::string& path, const std::vector<Eigen::Vector3f>& points, bool binary);

// Writes `bytes` to `path` through `path`.tmp and rename(), so a crash never leaves a
// truncated file under the final name.
Status WriteFileAtomic(const std::string& path, const std::string& bytes);

}  // namespace omni::octo
