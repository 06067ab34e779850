// Messages as a process receives them off the bus: LCM bytes decoded into the message type,
// then the receiver's own checks and decoding (depth and colour frames for the OctoMap builder,
// occupancy grids for map fusion, trajectories for re-posing, OctoMap trees for `octomap
// extract`). The first input byte picks the type. Seeds: one valid message of each type, made
// by our encoders (a small depth frame in every encoding, an RGB8 and a JPEG colour frame, a
// zlib grid, a trajectory, a tree in both forms and a colour tree).
#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>

#include <cmath>

#include "fuzz.h"
#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/kinect/depth_codec.h"
#include "omni/kinect/depth_message.h"
#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/depth_points.h"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/octomap_node.h"

namespace {

enum Kind : uint8_t { kDepth, kColor, kGrid, kTrajectory, kOctomap, kKinds };

template <class Msg>
bool Decode(const std::string& bytes, Msg* msg) {
  return omni::bus::DecodeMessage(msg, bytes.data(), static_cast<int>(bytes.size())) >= 0;
}

void Depth(const std::string& bytes) {
  omni::depth_image_t msg;
  if (!Decode(bytes, &msg)) return;
  auto image = omni::octo::FromDepthMessage(msg);
  // The Kinect side's reader (omni-depth-stream) is the stricter one (it also checks the
  // redundant uncompressed_size): what it decodes, the builder decodes to the same pixels.
  std::vector<uint16_t> px, builder_px;
  if (omni::kinect::ReadDepthMessage(msg, &px).ok()) {
    OMNI_FUZZ_CHECK(omni::octo::DecodeDepthData(msg.encoding, msg.data.data(), msg.data.size(),
                                                msg.width, msg.height, &builder_px)
                        .ok());
    OMNI_FUZZ_CHECK(px == builder_px);
  }
  if (!image.ok()) return;
  const omni::octo::DepthImage& d = image.value();
  OMNI_FUZZ_CHECK(d.width > 0 && d.height > 0);
  OMNI_FUZZ_CHECK(d.data.size() == static_cast<size_t>(d.width) * d.height);
  omni::octo::DepthToPointsOptions options;
  if (!omni::octo::CheckDepthFrame(d, options).ok()) return;
  auto points = omni::octo::DepthToPoints(d, options);
  if (!points.ok()) return;
  for (const auto& p : points.value()) OMNI_FUZZ_CHECK(p.allFinite());
}

void Color(const std::string& bytes) {
  omni::color_image_t msg;
  if (!Decode(bytes, &msg)) return;
  auto image = omni::octo::FromColorMessage(msg);
  if (!image.ok()) return;
  const omni::octo::ColorImage& c = image.value();
  OMNI_FUZZ_CHECK(c.width > 0 && c.height > 0);
  OMNI_FUZZ_CHECK(c.rgb.size() == 3 * static_cast<size_t>(c.width) * c.height);
}

void Grid(const std::string& bytes) {
  omni::occupancy_grid_t msg;
  if (!Decode(bytes, &msg)) return;
  auto grid = omni::bus::FromGridMessage(msg);
  if (!grid.ok()) return;
  const omni::io::GridMap& g = grid.value();
  OMNI_FUZZ_CHECK(g.width >= 0 && g.height >= 0);
  OMNI_FUZZ_CHECK(g.cells.size() == static_cast<size_t>(g.width) * g.height);
  OMNI_FUZZ_CHECK(g.cells.size() <= omni::io::kMaxGridCells);
  OMNI_FUZZ_CHECK(std::isfinite(g.resolution_m) && g.resolution_m > 0);
  OMNI_FUZZ_CHECK(std::isfinite(g.origin_x_m) && std::isfinite(g.origin_y_m));
  // What a receiver accepts, a sender can send again.
  OMNI_FUZZ_CHECK(omni::bus::ToGridMessage(g, 0, "fuzz").ok());
}

void Trajectory(const std::string& bytes) {
  omni::trajectory_t msg;
  if (!Decode(bytes, &msg)) return;
  auto poses = omni::octo::FromTrajectoryMessage(msg, "map");
  if (!poses.ok()) return;
  OMNI_FUZZ_CHECK(poses.value().size() == static_cast<size_t>(msg.num_poses));
  for (const auto& [utime, pose] : poses.value()) {
    (void)utime;
    OMNI_FUZZ_CHECK(std::isfinite(pose.x) && std::isfinite(pose.y) && std::isfinite(pose.theta));
  }
}

void Octomap(const std::string& bytes) {
  omni::octomap_t msg;
  if (!Decode(bytes, &msg)) return;
  const std::string data(msg.data.begin(), msg.data.end());
  const std::string why = omni::octo::CheckTreeBytes(data, msg.binary != 0, msg.tree_type);
  // The cheap check guards OctoMap's node readers (which trust the bytes: unbounded recursion,
  // reads past the end) and parses the header they never see, so the check and the parse agree:
  // a tree is read exactly when the check passes.
  if (msg.tree_type == "ColorOcTree") {
    // (ParseColorTree reads the full form whatever the message's binary flag says; the check
    // refuses a colour message that claims the binary form, which does not exist.)
    auto tree = omni::octo::ParseColorTree(data, "fuzz");
    if (msg.binary == 0) OMNI_FUZZ_CHECK(tree.ok() == why.empty());
  } else if (msg.tree_type == "OcTree") {
    auto tree = omni::octo::ParseTree(data, msg.binary != 0, "fuzz");
    OMNI_FUZZ_CHECK(tree.ok() == why.empty());
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
  switch (data[0] % kKinds) {
    case kDepth:
      Depth(bytes);
      break;
    case kColor:
      Color(bytes);
      break;
    case kGrid:
      Grid(bytes);
      break;
    case kTrajectory:
      Trajectory(bytes);
      break;
    default:
      Octomap(bytes);
      break;
  }
  return 0;
}

namespace {

template <class Msg>
void AddMessage(omni::fuzz::SeedList* seeds, Kind kind, const Msg& msg) {
  std::string bytes(static_cast<size_t>(msg.getEncodedSize()) + 1, '\0');
  bytes[0] = static_cast<char>(kind);
  OMNI_FUZZ_CHECK(msg.encode(bytes.data() + 1, 0, msg.getEncodedSize()) >= 0);
  seeds->Add(std::move(bytes));
}

}  // namespace

void omni::fuzz::Seeds(SeedList* seeds) {
  // An 8 x 6 depth frame of a slanted wall, in each encoding.
  const int w = 8, h = 6;
  std::vector<uint16_t> depth(w * h);
  for (int i = 0; i < w * h; ++i) depth[i] = static_cast<uint16_t>(900 + 7 * (i % w) + 3 * (i / w));
  depth[5] = 0;  // one pixel without a return
  for (auto enc : {omni::kinect::DepthEncoding::kRaw, omni::kinect::DepthEncoding::kZlib,
                   omni::kinect::DepthEncoding::kDeltaZlib}) {
    omni::depth_image_t msg{};
    OMNI_FUZZ_CHECK(omni::kinect::FillDepthMessage(depth.data(), w, h, enc, {}, &msg).ok());
    msg.fx = msg.fy = 6.0;
    msg.cx = 3.5;
    msg.cy = 2.5;
    msg.depth_scale = 1000;
    msg.frame = "camera";
    AddMessage(seeds, kDepth, msg);
  }
  // Colour: RGB8 and JPEG.
  std::vector<uint8_t> rgb(3 * w * h);
  for (size_t i = 0; i < rgb.size(); ++i) rgb[i] = static_cast<uint8_t>(i * 5);
  omni::color_image_t color{};
  color.width = w;
  color.height = h;
  color.fx = color.fy = 6.0;
  color.cx = 3.5;
  color.cy = 2.5;
  color.encoding = omni::color_image_t::ENCODING_RGB8;
  color.data = rgb;
  color.size = static_cast<int32_t>(rgb.size());
  AddMessage(seeds, kColor, color);
  if (auto jpeg = omni::octo::EncodeJpeg(rgb, w, h, 80); jpeg.ok()) {
    color.encoding = omni::color_image_t::ENCODING_JPEG;
    color.data = jpeg.value();
    color.size = static_cast<int32_t>(color.data.size());
    AddMessage(seeds, kColor, color);
  }
  // A grid with free, occupied and unknown cells.
  omni::io::GridMap grid;
  grid.width = 12;
  grid.height = 9;
  grid.origin_x_m = -0.3;
  grid.origin_y_m = 0.2;
  grid.cells.assign(grid.width * grid.height, -1);
  for (int c = 0; c < grid.width; ++c) {
    grid.at(c, 0) = 100;
    grid.at(c, 4) = 0;
  }
  AddMessage(seeds, kGrid, omni::bus::ToGridMessage(grid, 1, "fuzz").value());
  AddMessage(seeds, kGrid, omni::bus::ToGridMessage(grid, 1, "fuzz", /*raw=*/true).value());
  // A trajectory.
  omni::trajectory_t traj{};
  traj.frame = "map";
  traj.num_poses = 4;
  for (int i = 0; i < 4; ++i) {
    traj.pose_utime.push_back(1000 * (i + 1));
    traj.x_m.push_back(0.1 * i);
    traj.y_m.push_back(-0.05 * i);
    traj.yaw_rad.push_back(0.02 * i);
  }
  traj.utime = 4000;
  AddMessage(seeds, kTrajectory, traj);
  // Trees: a few occupied and free voxels.
  octomap::OcTree tree(0.1);
  octomap::ColorOcTree color_tree(0.1);
  for (int i = 0; i < 20; ++i) {
    const octomap::point3d p(0.1f * i, 0.05f * i, 0.3f);
    tree.updateNode(p, i % 3 != 0);
    color_tree.updateNode(p, true)->setColor(static_cast<uint8_t>(10 * i), 50, 200);
  }
  AddMessage(seeds, kOctomap, omni::octo::ToOctomapMessage(tree, 1, "map", "fuzz", true));
  AddMessage(seeds, kOctomap, omni::octo::ToOctomapMessage(tree, 1, "map", "fuzz", false));
  AddMessage(seeds, kOctomap, omni::octo::ToOctomapMessage(color_tree, 1, "map", "fuzz"));
}
