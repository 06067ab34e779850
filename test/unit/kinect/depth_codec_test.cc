// The bus depth codec: lossless round trips on real and synthetic frames, and rejection of
// every kind of damaged payload (never a crash, never a silently wrong image).
#include "omni/kinect/depth_codec.h"

#include <zlib.h>

#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "../common/test_paths.h"
#include "omni/kinect/depth_message.h"
#include "omni/octomap_builder/depth_io.h"

namespace omni::kinect {
namespace {

constexpr int8_t kRaw = 0, kZlib = 1, kDelta = 2;

std::vector<uint8_t> Encode(DepthEncoding e, const std::vector<uint16_t>& px, int w, int h,
                            DepthEncodeOptions o = {}) {
  std::vector<uint8_t> out;
  const Status s = EncodeDepth(e, px.data(), w, h, o, &out);
  EXPECT_TRUE(s.ok()) << s.message();
  return out;
}

// Encodes with every encoding (and DELTA_ZLIB with every predictor) and checks the decode is
// bit-exact. Returns the DELTA_ZLIB size with the default options.
size_t ExpectRoundTrips(const std::vector<uint16_t>& px, int w, int h) {
  size_t delta_size = 0;
  for (DepthEncoding e : {DepthEncoding::kRaw, DepthEncoding::kZlib, DepthEncoding::kDeltaZlib}) {
    const auto bytes = Encode(e, px, w, h);
    std::vector<uint16_t> out;
    const Status s = DecodeDepth(static_cast<int8_t>(e), bytes.data(), bytes.size(), w, h, &out);
    EXPECT_TRUE(s.ok()) << DepthEncodingName(static_cast<int8_t>(e)) << " " << w << "x" << h << ": "
                        << s.message();
    EXPECT_TRUE(out == px) << DepthEncodingName(static_cast<int8_t>(e)) << " " << w << "x" << h;
    if (e == DepthEncoding::kDeltaZlib) delta_size = bytes.size();
  }
  for (DepthPredictor p :
       {DepthPredictor::kLeft, DepthPredictor::kUp, DepthPredictor::kMed, DepthPredictor::kAvg}) {
    for (int strategy : {0, 3}) {
      DepthEncodeOptions o;
      o.predictor = p;
      o.zlib_strategy = strategy;
      const auto bytes = Encode(DepthEncoding::kDeltaZlib, px, w, h, o);
      std::vector<uint16_t> out;
      EXPECT_TRUE(DecodeDepth(kDelta, bytes.data(), bytes.size(), w, h, &out).ok());
      EXPECT_TRUE(out == px) << DepthPredictorName(p) << " strategy " << strategy << " " << w << "x"
                             << h;
    }
  }
  return delta_size;
}

std::vector<uint16_t> Noise(int w, int h, uint32_t seed, uint16_t lo = 0, uint16_t hi = 65535) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> d(lo, hi);
  std::vector<uint16_t> px(static_cast<size_t>(w) * h);
  for (auto& v : px) v = static_cast<uint16_t>(d(rng));
  return px;
}

// A smooth slanted plane with a hole and an edge, like a depth frame.
std::vector<uint16_t> Scene(int w, int h) {
  std::vector<uint16_t> px(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      uint16_t v = static_cast<uint16_t>(1500 + 3 * x + 2 * y);
      if (x > w / 2 && y > h / 3) v = static_cast<uint16_t>(800 + x);
      if ((x - 10) * (x - 10) + (y - 10) * (y - 10) < 25) v = 0;
      px[static_cast<size_t>(y) * w + x] = v;
    }
  return px;
}

void ExpectReject(int8_t enc, const std::vector<uint8_t>& bytes, int w, int h,
                  const std::string& why) {
  std::vector<uint16_t> out{1, 2, 3};
  const Status s = DecodeDepth(enc, bytes.data(), bytes.size(), w, h, &out);
  EXPECT_FALSE(s.ok()) << why;
  EXPECT_TRUE(out.empty()) << why;
  if (!s.ok()) {
    EXPECT_FALSE(s.message().empty());
  }
}

TEST(DepthCodec, RoundTripsRealFrames) {
  struct Seq {
    const char* dir;
    const char* ext;
  };
  int frames = 0;
  for (const Seq& q : {Seq{"rgbd/iclnuim-5frames", ".png"}, Seq{"rgbd/kinect-5frames", ".pgm"}}) {
    OMNI_REQUIRE_DATASET(dir, q.dir);
    for (int i = 1; i <= 5; ++i) {
      const std::string path = dir + "/depth/" + std::to_string(i) + q.ext;
      octo::DepthImage im;
      const Status s = octo::ReadDepthFile(path, &im);
      ASSERT_TRUE(s.ok()) << s.message();
      const size_t delta = ExpectRoundTrips(im.data, im.width, im.height);
      const auto zlib = Encode(DepthEncoding::kZlib, im.data, im.width, im.height);
      // The predictor has to pay for itself: clearly smaller than plain zlib of the bytes.
      EXPECT_LT(delta * 5, zlib.size() * 4) << path;
      ++frames;
    }
  }
  EXPECT_EQ(frames, 10);
}

TEST(DepthCodec, RoundTripsSyntheticEdgeCases) {
  ExpectRoundTrips(std::vector<uint16_t>(640 * 480, 0), 640, 480);
  ExpectRoundTrips(std::vector<uint16_t>(640 * 480, 65535), 640, 480);
  ExpectRoundTrips({0}, 1, 1);
  ExpectRoundTrips({65535}, 1, 1);
  ExpectRoundTrips({12345}, 1, 1);
  for (int w : {1, 2, 3, 7, 639, 641}) {
    for (int h : {1, 2, 5}) {
      ExpectRoundTrips(Noise(w, h, static_cast<uint32_t>(w * 31 + h)), w, h);
      ExpectRoundTrips(Scene(w, h), w, h);
    }
  }
  ExpectRoundTrips(Noise(640, 480, 7), 640, 480);
  ExpectRoundTrips(Noise(321, 243, 8, 0, 3), 321, 243);
  ExpectRoundTrips(Scene(641, 479), 641, 479);
  // Largest residuals: alternating extremes in both directions.
  std::vector<uint16_t> checker(33 * 17);
  for (int y = 0; y < 17; ++y)
    for (int x = 0; x < 33; ++x) checker[y * 33 + x] = ((x + y) & 1) ? 65535 : 0;
  ExpectRoundTrips(checker, 33, 17);
}

TEST(DepthCodec, EveryZlibLevelRoundTrips) {
  const auto px = Scene(64, 48);
  for (int level = 0; level <= 9; ++level) {
    DepthEncodeOptions o;
    o.zlib_level = level;
    o.zlib_strategy = 0;
    for (DepthEncoding e : {DepthEncoding::kZlib, DepthEncoding::kDeltaZlib}) {
      const auto bytes = Encode(e, px, 64, 48, o);
      std::vector<uint16_t> out;
      EXPECT_TRUE(
          DecodeDepth(static_cast<int8_t>(e), bytes.data(), bytes.size(), 64, 48, &out).ok());
      EXPECT_EQ(out, px) << "level " << level;
    }
  }
}

TEST(DepthCodec, EncoderRejectsBadArguments) {
  std::vector<uint16_t> px(4, 1);
  std::vector<uint8_t> out;
  DepthEncodeOptions o;
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kRaw, px.data(), 0, 4, o, &out).ok());
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kRaw, px.data(), 2, -2, o, &out).ok());
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kRaw, px.data(), kMaxDepthSide + 1, 1, o, &out).ok());
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kRaw, nullptr, 2, 2, o, &out).ok());
  EXPECT_FALSE(EncodeDepth(static_cast<DepthEncoding>(9), px.data(), 2, 2, o, &out).ok());
  o.zlib_level = 10;
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kZlib, px.data(), 2, 2, o, &out).ok());
  o = {};
  o.zlib_strategy = 9;
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kDeltaZlib, px.data(), 2, 2, o, &out).ok());
  o = {};
  o.predictor = static_cast<DepthPredictor>(0);
  EXPECT_FALSE(EncodeDepth(DepthEncoding::kDeltaZlib, px.data(), 2, 2, o, &out).ok());
  EXPECT_TRUE(out.empty());
}

TEST(DepthCodec, RejectsWrongSizesAndEncodings) {
  const int w = 31, h = 9;
  const auto px = Scene(w, h);
  const auto raw = Encode(DepthEncoding::kRaw, px, w, h);
  const auto z = Encode(DepthEncoding::kZlib, px, w, h);
  const auto d = Encode(DepthEncoding::kDeltaZlib, px, w, h);
  for (int8_t e : {kRaw, kZlib, kDelta}) {
    const auto& b = e == kRaw ? raw : e == kZlib ? z : d;
    ExpectReject(e, b, w + 1, h, "wider");
    ExpectReject(e, b, w, h - 1, "shorter");
    ExpectReject(e, b, 0, h, "zero width");
    ExpectReject(e, b, w, -1, "negative height");
    ExpectReject(e, b, kMaxDepthSide + 1, h, "too wide");
    ExpectReject(e, {}, w, h, "empty payload");
  }
  // Only DELTA_ZLIB carries its own size: RAW and ZLIB of a transposed image are the same
  // number of bytes.
  ExpectReject(kDelta, d, h, w, "transposed");
  ExpectReject(3, raw, w, h, "unknown encoding 3");
  ExpectReject(-1, raw, w, h, "unknown encoding -1");
  ExpectReject(kZlib, raw, w, h, "raw bytes labelled ZLIB");
  ExpectReject(kDelta, z, w, h, "plain zlib labelled DELTA_ZLIB");
  ExpectReject(kZlib, d, w, h, "DELTA_ZLIB labelled ZLIB");
  ExpectReject(kRaw, z, w, h, "zlib labelled RAW");
  // A tiny payload claiming the largest image is refused before inflating.
  ExpectReject(kZlib, z, kMaxDepthSide, kMaxDepthSide, "huge claim");
  ExpectReject(kDelta, d, kMaxDepthSide, kMaxDepthSide, "huge claim");
}

TEST(DepthCodec, RejectsEveryTruncationAndTrailingBytes) {
  const int w = 23, h = 11;
  const auto px = Scene(w, h);
  for (int8_t e : {kRaw, kZlib, kDelta}) {
    const auto full = Encode(static_cast<DepthEncoding>(e), px, w, h);
    for (size_t n = 0; n < full.size(); ++n) {
      ExpectReject(e, std::vector<uint8_t>(full.begin(), full.begin() + n), w, h,
                   std::string(DepthEncodingName(e)) + " truncated to " + std::to_string(n));
    }
    auto longer = full;
    longer.push_back(0);
    ExpectReject(e, longer, w, h, std::string(DepthEncodingName(e)) + " with a trailing byte");
  }
}

TEST(DepthCodec, RejectsDamagedHeader) {
  const int w = 40, h = 30;
  const auto px = Scene(w, h);
  const auto good = Encode(DepthEncoding::kDeltaZlib, px, w, h);
  ASSERT_GT(good.size(), kDeltaHeaderBytes);
  for (size_t i = 0; i < kDeltaHeaderBytes; ++i) {
    for (int bit = 0; bit < 8; ++bit) {
      auto bad = good;
      bad[i] ^= static_cast<uint8_t>(1u << bit);
      ExpectReject(kDelta, bad, w, h,
                   "header byte " + std::to_string(i) + " bit " + std::to_string(bit));
    }
  }
  // Well-formed headers (valid checksum) with fields this decoder does not accept.
  auto with = [&](size_t at, uint8_t value) {
    auto b = good;
    b[at] = value;
    const uint32_t c = static_cast<uint32_t>(crc32(0L, b.data(), 12));
    for (int k = 0; k < 4; ++k) b[12 + k] = static_cast<uint8_t>(c >> (8 * k));
    return b;
  };
  ExpectReject(kDelta, with(2, 2), w, h, "version 2");
  ExpectReject(kDelta, with(3, 0), w, h, "predictor 0");
  ExpectReject(kDelta, with(3, 200), w, h, "predictor 200");
  ExpectReject(kDelta, with(4, 41), w, h, "header width 41");
  ExpectReject(kDelta, with(8, 31), w, h, "header height 31");
  // The unchanged header still decodes (the helper itself is sound).
  std::vector<uint16_t> out;
  auto same = with(3, good[3]);
  ASSERT_TRUE(DecodeDepth(kDelta, same.data(), same.size(), w, h, &out).ok());
  EXPECT_EQ(out, px);
}

TEST(DepthCodec, DamagedBodyIsAnErrorOrTheExactImage) {
  // A flipped bit in the zlib stream is caught by inflate or the Adler-32; the only flips that
  // decode are in bits inflate never reads (padding of the last byte), and they must give back
  // the exact image.
  const int w = 37, h = 13;
  const auto px = Scene(w, h);
  for (int8_t e : {kZlib, kDelta}) {
    const auto good = Encode(static_cast<DepthEncoding>(e), px, w, h);
    const size_t start = e == kDelta ? kDeltaHeaderBytes : 0;
    int rejected = 0, total = 0;
    for (size_t i = start; i < good.size(); ++i) {
      for (int bit = 0; bit < 8; ++bit) {
        auto bad = good;
        bad[i] ^= static_cast<uint8_t>(1u << bit);
        std::vector<uint16_t> out;
        const Status s = DecodeDepth(e, bad.data(), bad.size(), w, h, &out);
        ++total;
        if (!s.ok()) {
          ++rejected;
          EXPECT_TRUE(out.empty());
        } else {
          EXPECT_EQ(out, px) << DepthEncodingName(e) << " byte " << i << " bit " << bit;
        }
      }
    }
    EXPECT_GT(rejected, total * 9 / 10) << DepthEncodingName(e);
  }
}

TEST(DepthCodec, RandomGarbageNeverCrashes) {
  std::mt19937 rng(42);
  for (int t = 0; t < 300; ++t) {
    std::vector<uint8_t> junk(rng() % 200);
    for (auto& b : junk) b = static_cast<uint8_t>(rng());
    if (t % 3 == 0 && junk.size() >= 16) {  // a valid-looking header over garbage
      junk[0] = 'O';
      junk[1] = 'D';
      junk[2] = 1;
      junk[3] = 3;
      for (int k = 0; k < 4; ++k) junk[4 + k] = static_cast<uint8_t>(k == 0 ? 8 : 0);
      for (int k = 0; k < 4; ++k) junk[8 + k] = static_cast<uint8_t>(k == 0 ? 4 : 0);
      const uint32_t c = static_cast<uint32_t>(crc32(0L, junk.data(), 12));
      for (int k = 0; k < 4; ++k) junk[12 + k] = static_cast<uint8_t>(c >> (8 * k));
    }
    for (int8_t e : {kZlib, kDelta}) {
      std::vector<uint16_t> out;
      (void)DecodeDepth(e, junk.data(), junk.size(), 8, 4, &out);
    }
  }
}

// Out of line: inlined into the test, GCC flags a false maybe-uninitialized in the generated
// decode().
[[gnu::noinline]] int DecodeWire(const std::vector<uint8_t>& wire, omni::depth_image_t* msg) {
  return msg->decode(wire.data(), 0, static_cast<int>(wire.size()));
}

TEST(DepthMessage, FillsAndReadsThroughLcmBytes) {
  const int w = 64, h = 48;
  const auto px = Scene(w, h);
  for (DepthEncoding e : {DepthEncoding::kRaw, DepthEncoding::kZlib, DepthEncoding::kDeltaZlib}) {
    omni::depth_image_t msg{};
    msg.utime = 123;
    msg.seq = 7;
    msg.frame = "depth_optical";
    msg.depth_scale = 1000;
    ASSERT_TRUE(FillDepthMessage(px.data(), w, h, e, {}, &msg).ok());
    EXPECT_EQ(msg.width, w);
    EXPECT_EQ(msg.height, h);
    EXPECT_EQ(msg.encoding, static_cast<int8_t>(e));
    EXPECT_EQ(msg.uncompressed_size, w * h * 2);
    EXPECT_EQ(static_cast<size_t>(msg.size), msg.data.size());
    // Through the wire format and back.
    std::vector<uint8_t> wire(msg.getEncodedSize());
    ASSERT_EQ(msg.encode(wire.data(), 0, static_cast<int>(wire.size())),
              static_cast<int>(wire.size()));
    omni::depth_image_t back;
    ASSERT_EQ(DecodeWire(wire, &back), static_cast<int>(wire.size()));
    std::vector<uint16_t> out;
    const Status s = ReadDepthMessage(back, &out);
    ASSERT_TRUE(s.ok()) << s.message();
    EXPECT_EQ(out, px);
    // Inconsistent bookkeeping is rejected.
    auto bad = back;
    bad.uncompressed_size += 2;
    EXPECT_FALSE(ReadDepthMessage(bad, &out).ok());
    bad = back;
    bad.size -= 1;
    EXPECT_FALSE(ReadDepthMessage(bad, &out).ok());
    bad = back;
    bad.width = 32;
    EXPECT_FALSE(ReadDepthMessage(bad, &out).ok());
  }
}

}  // namespace
}  // namespace omni::kinect
