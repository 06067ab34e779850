// Two processes on the bus: omni-depth-stream sends DELTA_ZLIB depth at 30 Hz over LCM UDP
// multicast inside a private network namespace (nothing leaves the machine) and the receiver
// checks every frame arrives and decodes bit-exact. 5 s here; `--seconds 60` for the long run.
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "../tools/run.h"

namespace omni {
namespace {

bool CanMakeNetns() { return testing::Run("unshare -n true").exit_code == 0; }

testing::RunResult Stream(const std::string& dir, const std::string& args) {
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304'\n"
      << testing::Bin("omni-depth-stream") << " recv " << args << " --timeout 5 & r=$!\n"
      << "sleep 0.5\n"
      << testing::Bin("omni-depth-stream") << " send " << args << "\n"
      << "s=$?\nwait $r\nexit $((s * 10 + $?))\n";
  }
  return testing::Run("timeout 40 unshare -n bash " + dir + "/run.sh");
}

TEST(DepthStream, DeltaZlibDatasetFramesAt30HzLoseNothing) {
  OMNI_REQUIRE_DATASET(seq, "rgbd/kinect-5frames");
  if (!CanMakeNetns())
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const auto r = Stream(testing::TempDir(), "--sequence " + seq + " --rate 30 --seconds 5");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("sent 150 of 150 frames (delta"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("received 150 of 150 frames: lost 0, decode errors 0, mismatches 0"),
            std::string::npos)
      << r.output;
}

TEST(DepthStream, SyntheticFramesAt30HzLoseNothing) {
  if (!CanMakeNetns())
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const auto r = Stream(testing::TempDir(), "--rate 30 --seconds 3");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("received 90 of 90 frames: lost 0, decode errors 0, mismatches 0"),
            std::string::npos)
      << r.output;
}

TEST(DepthStream, ReceiverReportsMissingFrames) {
  // Nobody sends: the receiver must give up after its timeout and fail, naming the loss.
  if (!CanMakeNetns())
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const auto r = testing::Run(
      "timeout 20 unshare -n bash -c 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && " +
      testing::Bin("omni-depth-stream") +
      " recv --url \"udpm://239.255.76.67:7667?ttl=0\" --frames 3 --timeout 1'");
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("received 0 of 3 frames: lost 3"), std::string::npos) << r.output;
}

TEST(DepthStreamCli, HelpAndBadArguments) {
  EXPECT_EQ(testing::Run(testing::Bin("omni-depth-stream") + " --help").exit_code, 0);
  EXPECT_NE(testing::Run(testing::Bin("omni-depth-stream")).exit_code, 0);
  EXPECT_NE(testing::Run(testing::Bin("omni-depth-stream") + " send --rate x").exit_code, 0);
  EXPECT_NE(testing::Run(testing::Bin("omni-depth-stream") + " send --encoding lzma --url memq://")
                .exit_code,
            0);
  EXPECT_NE(
      testing::Run(testing::Bin("omni-depth-stream") + " recv --sequence /nonexistent").exit_code,
      0);
}

}  // namespace
}  // namespace omni
