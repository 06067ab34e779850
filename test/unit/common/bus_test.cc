#include "omni/bus/bus.h"

#include <cstdio>
#include <filesystem>
#include <set>

#include <gtest/gtest.h>

#include "omni/bus/heartbeat.h"
#include "omni/heartbeat_t.hpp"
#include "omni/pose2d_t.hpp"

namespace omni::bus {
namespace {

void Pump(Bus& bus) {
  while (bus.HandleTimeout(0) > 0) {
  }
}

TEST(Bus, TypedRoundTripOnMemq) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  std::vector<omni::pose2d_t> got;
  (*bus)->Subscribe<omni::pose2d_t>("POSE",
                                    [&](const omni::pose2d_t& m, int64_t) { got.push_back(m); });
  omni::pose2d_t p{};
  p.utime = 42;
  p.frame = "map";
  p.source = "test";
  p.x_m = 1.5;
  ASSERT_TRUE((*bus)->Publish("POSE", p));
  Pump(**bus);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].utime, 42);
  EXPECT_EQ(got[0].x_m, 1.5);
  EXPECT_EQ((*bus)->counters().msgs_in, 1);
  EXPECT_EQ((*bus)->counters().msgs_out, 1);
}

TEST(Bus, UndecodableMessagesAreCountedNotDelivered) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  int delivered = 0;
  (*bus)->Subscribe<omni::pose2d_t>("POSE", [&](const omni::pose2d_t&, int64_t) { ++delivered; });
  const char garbage[] = "this is not a pose2d_t";
  ASSERT_TRUE((*bus)->PublishRaw("POSE", garbage, sizeof(garbage)));
  // A valid message of another type on the same channel: wrong fingerprint.
  omni::heartbeat_t hb{};
  hb.process = "x";
  ASSERT_TRUE((*bus)->Publish("POSE", hb));
  // A truncated valid message.
  omni::pose2d_t p{};
  p.frame = "map";
  std::vector<uint8_t> buf(static_cast<size_t>(p.getEncodedSize()));
  p.encode(buf.data(), 0, static_cast<int>(buf.size()));
  ASSERT_TRUE((*bus)->PublishRaw("POSE", buf.data(), static_cast<int>(buf.size() - 5)));
  Pump(**bus);
  EXPECT_EQ(delivered, 0);
  EXPECT_EQ((*bus)->counters().decode_errors, 3);
  EXPECT_EQ((*bus)->last_decode_error(), "POSE");
}

TEST(Bus, HeartbeatCarriesCounters) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  std::vector<omni::heartbeat_t> got;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { got.push_back(m); });
  ManualClock clock(1'000'000);
  Heartbeat hb(bus->get(), "tester", &clock);
  int64_t resyncs = 7;
  hb.AddCounter("resyncs", [&] { return resyncs; });
  hb.SetState(omni::heartbeat_t::STATE_DEGRADED, "device flaky");
  ASSERT_TRUE(hb.Tick());
  EXPECT_FALSE(hb.Tick()) << "second tick within the period publishes nothing";
  clock.Advance(1'000'000);
  resyncs = 9;
  ASSERT_TRUE(hb.Tick());
  Pump(**bus);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[1].process, "tester");
  EXPECT_EQ(got[1].state, omni::heartbeat_t::STATE_DEGRADED);
  EXPECT_EQ(got[1].uptime_us, 1'000'000);
  ASSERT_GE(got[1].num_counters, 1);
  EXPECT_EQ(got[1].counter_names[0], "resyncs");
  EXPECT_EQ(got[1].counter_values[0], 9);
  EXPECT_GT(got[1].rss_mb, 0.f);
}

TEST(Bus, JavaJarHoldsEveryType) {
  const std::string jar = std::string(OMNI_BINARY_DIR) + "/omni_lcmtypes.jar";
  ASSERT_TRUE(std::filesystem::exists(jar)) << jar;
  std::set<std::string> types;
  for (const auto& e :
       std::filesystem::directory_iterator(std::string(OMNI_SOURCE_DIR) + "/common/lcmtypes"))
    if (e.path().extension() == ".lcm") types.insert(e.path().stem().string());
  ASSERT_GE(types.size(), 13u);
  FILE* p = popen(("jar tf '" + jar + "'").c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::set<std::string> classes;
  char line[512];
  while (fgets(line, sizeof(line), p)) {
    std::string s(line);
    while (!s.empty() && (s.back() == '\n' || s.back() == '\r')) s.pop_back();
    classes.insert(s);
  }
  ASSERT_EQ(pclose(p), 0);
  for (const auto& t : types)
    EXPECT_TRUE(classes.count("omni/" + t + ".class")) << t << " missing from the jar";
}

}  // namespace
}  // namespace omni::bus
