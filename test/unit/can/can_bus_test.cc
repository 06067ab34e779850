// The user-space CAN bus (several nodes, several processes, overrun, link down/up) and the
// SocketCAN implementation (skipped where the kernel has no CAN).
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <string>

#include <sys/wait.h>
#include <unistd.h>

#include "omni/can/can_bus.h"
#include "omni/can/shm_can_bus.h"
#include "omni/can/socket_can_bus.h"

namespace omni::can {
namespace {

std::string UniqueName(const char* what) {
  return std::string("test-") + what + "-" + std::to_string(getpid());
}

struct BusName {
  explicit BusName(const char* what) : name(UniqueName(what)) { (void)ShmCanBus::Remove(name); }
  ~BusName() { (void)ShmCanBus::Remove(name); }
  std::string name;
};

Frame MakeFrame(uint32_t id, uint8_t fill) {
  Frame f;
  f.id = id;
  f.dlc = 8;
  for (int i = 0; i < 8; ++i) f.data[i] = static_cast<uint8_t>(fill + i);
  return f;
}

TEST(ShmCanBusTest, EveryOtherNodeHearsEachFrame) {
  BusName bus("nodes");
  auto a = OpenCanBus("shm:" + bus.name);
  auto b = OpenCanBus("shm:" + bus.name);
  auto c = OpenCanBus("shm:" + bus.name);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  ASSERT_TRUE((*a)->Send(MakeFrame(0x123, 7)).ok());
  Frame f;
  for (auto* node : {&b, &c}) {
    auto r = (**node)->Receive(&f, 100);
    ASSERT_TRUE(r.ok());
    ASSERT_TRUE(r.value());
    EXPECT_EQ(f.id, 0x123u);
    EXPECT_EQ(f.dlc, 8);
    EXPECT_EQ(f.data[0], 7);
    EXPECT_EQ(f.data[7], 14);
  }
  // The sender does not hear itself (as with SocketCAN's default: no local loopback).
  auto r = (*a)->Receive(&f, 0);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r.value());
  EXPECT_EQ((*a)->stats().tx_frames, 1);
  EXPECT_EQ((*b)->stats().rx_frames, 1);
}

TEST(ShmCanBusTest, TimeoutReturnsFalse) {
  BusName bus("timeout");
  auto a = ShmCanBus::Open(bus.name);
  ASSERT_TRUE(a.ok());
  Frame f;
  const auto t0 = std::chrono::steady_clock::now();
  auto r = (*a)->Receive(&f, 30);
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r.value());
  EXPECT_GE(ms, 25.0);
  EXPECT_LT(ms, 500.0);
}

TEST(ShmCanBusTest, SharedAcrossProcessesInOrder) {
  BusName bus("procs");
  auto rx = ShmCanBus::Open(bus.name);
  ASSERT_TRUE(rx.ok());
  constexpr int kFrames = 2000;
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto tx = ShmCanBus::Open(bus.name);
    if (!tx.ok()) _exit(2);
    for (int i = 0; i < kFrames; ++i) {
      Frame f = MakeFrame(static_cast<uint32_t>(i % 0x800), 0);
      std::memcpy(f.data, &i, sizeof(i));
      if (!(*tx)->Send(f).ok()) _exit(3);
      if (i % 256 == 255) usleep(1000);  // let the reader keep up (ring of 4096)
    }
    _exit(0);
  }
  int got = 0;
  Frame f;
  while (got < kFrames) {
    auto r = (*rx)->Receive(&f, 2000);
    ASSERT_TRUE(r.ok());
    ASSERT_TRUE(r.value()) << "timed out after " << got << " frames";
    int i = -1;
    std::memcpy(&i, f.data, sizeof(i));
    ASSERT_EQ(i, got) << "frames out of order or lost";
    ++got;
  }
  int status = 0;
  waitpid(child, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  EXPECT_EQ((*rx)->stats().rx_overruns, 0);
}

TEST(ShmCanBusTest, SlowReaderCountsOverrun) {
  BusName bus("overrun");
  auto a = ShmCanBus::Open(bus.name);
  auto b = ShmCanBus::Open(bus.name);
  ASSERT_TRUE(a.ok() && b.ok());
  const int n = static_cast<int>(ShmCanBus::kSlots) + 500;
  for (int i = 0; i < n; ++i) ASSERT_TRUE((*a)->Send(MakeFrame(0x10, 0)).ok());
  Frame f;
  int got = 0;
  for (;;) {
    auto r = (*b)->Receive(&f, 0);
    ASSERT_TRUE(r.ok());
    if (!r.value()) break;
    ++got;
  }
  EXPECT_GT((*b)->stats().rx_overruns, 0);
  EXPECT_EQ(got + (*b)->stats().rx_overruns, n);
}

TEST(ShmCanBusTest, LinkDownAndUp) {
  BusName bus("link");
  auto a = ShmCanBus::Open(bus.name);
  auto b = ShmCanBus::Open(bus.name);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE(ShmCanBus::SetLinkUp(bus.name, false).ok());
  const Status s = (*a)->Send(MakeFrame(1, 1));
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
  Frame f;
  auto r = (*b)->Receive(&f, 10);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kUnavailable);
  auto c = ShmCanBus::Open(bus.name);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("down"), std::string::npos);
  ASSERT_TRUE(ShmCanBus::SetLinkUp(bus.name, true).ok());
  ASSERT_TRUE((*a)->Send(MakeFrame(2, 2)).ok());
  r = (*b)->Receive(&f, 100);
  ASSERT_TRUE(r.ok() && r.value());
  EXPECT_EQ(f.id, 2u);
}

TEST(ShmCanBusTest, RejectsBadUrlsAndFrames) {
  // A bare interface name is SocketCAN's; names that no interface can have are refused.
  auto bare = ParseCanUrl("can0");
  ASSERT_TRUE(bare.ok());
  EXPECT_EQ(bare->kind, CanUrl::Kind::kSocketCan);
  EXPECT_EQ(bare->name, "can0");
  auto full = ParseCanUrl("socketcan:vcan0");
  ASSERT_TRUE(full.ok());
  EXPECT_EQ(full->name, "vcan0");
  EXPECT_EQ(ParseCanUrl("shm:sim")->kind, CanUrl::Kind::kShm);
  for (const char* u :
       {"", "socketcan:", "udp:can0", "can 0", "a23456789012345678", "shm:", "shm:a/b"}) {
    auto r = ParseCanUrl(u);
    ASSERT_FALSE(r.ok()) << u;
    EXPECT_EQ(r.error().code, ErrorCode::kInvalidArgument) << u;
    EXPECT_NE(r.error().message.find("can0"), std::string::npos) << r.error().message;
  }
  EXPECT_EQ(OpenCanBus("udp:can0").error().code, ErrorCode::kInvalidArgument);
  // A simulator bus named without its prefix: whatever SocketCAN says, the error points at it.
  BusName sim("hint");
  auto held = ShmCanBus::Open(sim.name);
  ASSERT_TRUE(held.ok());
  if (sim.name.size() < 16) {
    auto bare_sim = OpenCanBus(sim.name);
    ASSERT_FALSE(bare_sim.ok());
    EXPECT_NE(bare_sim.error().message.find("did you mean --can shm:" + sim.name),
              std::string::npos)
        << bare_sim.error().message;
  }
  EXPECT_EQ(OpenCanBus("shm:../etc").error().code, ErrorCode::kInvalidArgument);
  EXPECT_EQ(OpenCanBus("shm:").error().code, ErrorCode::kInvalidArgument);
  BusName bus("bad");
  auto a = ShmCanBus::Open(bus.name);
  ASSERT_TRUE(a.ok());
  Frame f = MakeFrame(0x800, 0);  // 12 bits: not a standard id
  EXPECT_EQ((*a)->Send(f).error().code, ErrorCode::kInvalidArgument);
  f = MakeFrame(0x12, 0);
  f.dlc = 9;
  EXPECT_EQ((*a)->Send(f).error().code, ErrorCode::kInvalidArgument);
}

TEST(SocketCanBusTest, OpensCan0OrSkips) {
  auto bus = SocketCanBus::Open("can0");
  if (!bus.ok()) {
    // This kernel: socket(PF_CAN) fails with EAFNOSUPPORT; elsewhere can0 may be absent.
    EXPECT_EQ(bus.error().code, ErrorCode::kUnavailable);
    GTEST_SKIP() << "SocketCAN unavailable: " << bus.error().message;
  }
  EXPECT_EQ((*bus)->name(), "socketcan:can0");
  Frame f;
  auto r = (*bus)->Receive(&f, 10);
  EXPECT_TRUE(r.ok() || r.error().code == ErrorCode::kUnavailable);
}

}  // namespace
}  // namespace omni::can
