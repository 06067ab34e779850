// OpenNI2's built-in "Dummy" device (libDummyDevice in the Debian driver directory): no
// hardware needed. Opens it through OpenNI2DepthSource, then runs omni-kinect-driver on it,
// and checks a missing device makes the driver exit 1 naming the URI.
#include <string>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "../tools/run.h"
#include "omni/color_image_t.hpp"
#include "omni/depth_image_t.hpp"
#include "omni/heartbeat_t.hpp"
#include "omni/io/lcm_log.h"
#include "omni/kinect/depth_message.h"
#include "omni/kinect/openni2_source.h"

namespace omni::kinect {
namespace {

std::string Config() { return std::string(OMNI_SOURCE_DIR) + "/config/kinect_driver.yaml"; }

TEST(KinectDummy, OpenNI2SourceStreamsDepthAndColour) {
  OpenNI2Options o;
  o.uri = "Dummy";
  OpenNI2DepthSource src(o);
  const Status st = src.Open();
  if (!st.ok()) GTEST_SKIP() << "OpenNI2 Dummy device not available: " << st.error().ToString();
  int depth = 0, color = 0;
  SourceFrames f;
  for (int i = 0; i < 200 && (depth < 5 || color < 2); ++i) {
    ASSERT_TRUE(src.Read(500, &f).ok());
    if (f.has_depth) {
      ++depth;
      EXPECT_GT(f.depth.width, 0);
      EXPECT_EQ(f.depth.depth_mm.size(),
                static_cast<size_t>(f.depth.width) * static_cast<size_t>(f.depth.height));
      EXPECT_GT(f.depth.intrinsics.fx, 0);  // the Dummy reports no FOV: the fallback applies
      EXPECT_GT(f.depth.intrinsics.fy, 0);
      EXPECT_GE(f.depth.frame_index, 0);
    }
    if (f.has_color) {
      ++color;
      EXPECT_EQ(f.color.rgb.size(),
                static_cast<size_t>(f.color.width) * static_cast<size_t>(f.color.height) * 3);
    }
  }
  EXPECT_GE(depth, 5);
  EXPECT_GE(color, 2);
  // The Dummy device accepts RGB888: colour is on and nothing is reported as missing.
  EXPECT_TRUE(src.color_open());
  EXPECT_EQ(src.Warning(), "");
  src.Close();
}

TEST(KinectDummy, ClosedDeviceReopensInTheSameProcess) {
  // What the driver does after a loss: close, then open again without restarting OpenNI2.
  OpenNI2Options o;
  o.uri = "Dummy";
  o.color = false;
  OpenNI2DepthSource src(o);
  if (!src.Open().ok()) GTEST_SKIP() << "OpenNI2 Dummy device not available";
  for (int round = 0; round < 2; ++round) {
    int depth = 0;
    SourceFrames f;
    for (int i = 0; i < 50 && depth < 2; ++i) {
      ASSERT_TRUE(src.Read(500, &f).ok());
      if (f.has_depth) ++depth;
      EXPECT_FALSE(f.has_color);
    }
    EXPECT_EQ(depth, 2) << "round " << round;
    src.Close();
    SourceFrames none;
    EXPECT_FALSE(src.Read(10, &none).ok());  // closed: an error, not a crash
    if (round == 0) {
      ASSERT_TRUE(src.Open().ok());
    }
  }
}

TEST(KinectDummy, DriverRunsOnTheDummyDevice) {
  const auto r = testing::Run("timeout 30 " + testing::Bin("omni-kinect-driver") + " --config " +
                              Config() + " --uri Dummy --lcm-url memq:// --duration-s 1 2>&1");
  if (r.output.find("cannot open") != std::string::npos) {
    GTEST_SKIP() << "OpenNI2 Dummy device not available: " << r.output;
  }
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("depth and"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("published 0 depth"), std::string::npos) << r.output;
}

int64_t Counter(const omni::heartbeat_t& hb, const std::string& name) {
  for (int i = 0; i < hb.num_counters; ++i) {
    if (hb.counter_names[static_cast<size_t>(i)] == name) {
      return hb.counter_values[static_cast<size_t>(i)];
    }
  }
  return -1;
}

TEST(KinectDummy, DriverPublishesDecodableDepthColourAndHeartbeatToALog) {
  const std::string log = testing::TempDir() + "/kinect.lcmlog";
  const auto r =
      testing::Run("timeout 30 " + testing::Bin("omni-kinect-driver") + " --config " + Config() +
                   " --uri Dummy --duration-s 1.5 --lcm-url 'file://" + log + "?mode=w' 2>&1");
  if (r.output.find("cannot open") != std::string::npos) {
    GTEST_SKIP() << "OpenNI2 Dummy device not available: " << r.output;
  }
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto reader = io::LcmLogReader::Open(log);
  ASSERT_TRUE(reader.ok()) << reader.error().message;
  io::LcmLogEvent ev;
  int depth = 0, color = 0, heartbeats = 0, ok_heartbeats = 0;
  omni::heartbeat_t last_hb;
  while (true) {
    auto more = reader->Next(&ev);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    if (ev.channel == "DEPTH") {
      omni::depth_image_t m;
      ASSERT_GT(m.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())), 0);
      EXPECT_EQ(m.encoding, omni::depth_image_t::ENCODING_DELTA_ZLIB);
      EXPECT_EQ(m.seq, depth);
      EXPECT_GT(m.fx, 0);
      EXPECT_GT(m.fy, 0);
      EXPECT_DOUBLE_EQ(m.cx, (m.width - 1) / 2.0);
      EXPECT_DOUBLE_EQ(m.depth_scale, 1000.0);
      std::vector<uint16_t> px;
      ASSERT_TRUE(ReadDepthMessage(m, &px).ok());
      EXPECT_EQ(px.size(), static_cast<size_t>(m.width) * static_cast<size_t>(m.height));
      ++depth;
    } else if (ev.channel == "RGB") {
      omni::color_image_t m;
      ASSERT_GT(m.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())), 0);
      EXPECT_EQ(m.size, m.width * m.height * 3);
      ++color;
    } else if (ev.channel == "HEARTBEAT") {
      ASSERT_GT(last_hb.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())), 0);
      ++heartbeats;
      // STARTING until the first depth frame, then OK (DEGRADED would mean colour off).
      EXPECT_TRUE(last_hb.state == omni::heartbeat_t::STATE_STARTING ||
                  last_hb.state == omni::heartbeat_t::STATE_OK ||
                  last_hb.state == omni::heartbeat_t::STATE_STOPPING)
          << int{last_hb.state} << ": " << last_hb.status_text;
      if (last_hb.state == omni::heartbeat_t::STATE_OK) ++ok_heartbeats;
    }
  }
  EXPECT_GE(depth, 20);  // 30 Hz for 1.5 s
  EXPECT_GE(color, 10);
  ASSERT_GE(heartbeats, 2);
  EXPECT_GE(ok_heartbeats, 1);
  EXPECT_EQ(last_hb.process, "kinect_driver");
  EXPECT_EQ(last_hb.state, omni::heartbeat_t::STATE_STOPPING);
  EXPECT_EQ(Counter(last_hb, "depth_messages"), depth);
  EXPECT_EQ(Counter(last_hb, "frames"), depth);
  EXPECT_EQ(Counter(last_hb, "encode_errors"), 0);
  EXPECT_EQ(Counter(last_hb, "reconnects"), 0);
  EXPECT_EQ(Counter(last_hb, "device_errors"), 0);
  EXPECT_EQ(Counter(last_hb, "connect_failures"), 0);
  EXPECT_EQ(Counter(last_hb, "bad_frames"), 0);
  EXPECT_GE(Counter(last_hb, "dropped_frames"), 0);
}

TEST(KinectDummy, MissingDeviceExitsOneNamingTheUri) {
  const auto r =
      testing::Run("timeout 30 " + testing::Bin("omni-kinect-driver") + " --config " + Config() +
                   " --uri nosuch://cam7 --lcm-url memq:// --duration-s 1 2>&1");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("nosuch://cam7"), std::string::npos) << r.output;
}

TEST(KinectDummy, HelpExitsZero) {
  const auto r = testing::Run(testing::Bin("omni-kinect-driver") + " --help 2>&1");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.output.find("--uri"), std::string::npos);
}

}  // namespace
}  // namespace omni::kinect
