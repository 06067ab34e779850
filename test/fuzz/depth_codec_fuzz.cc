// The lossless depth codec (Kinect driver -> DEPTH -> OctoMap builder). Two halves:
//   - decoding: any payload with any header (encoding, width, height) decodes to exactly
//     width x height pixels or is an error;
//   - the round trip: the input read as pixels is encoded with every encoding and predictor
//     and must decode to the same pixels.
// Seeds: frames of the real RGB-D sequences are too large for a fuzz input, so the seeds are
// small frames our encoder made from a slanted wall with holes.
#include "fuzz.h"
#include "omni/kinect/depth_codec.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace omni::kinect;
  omni::fuzz::Reader in(data, size);
  const auto encoding = static_cast<int8_t>(in.U8());
  const int width = in.U8();  // small sides: a fuzz input cannot fill a real frame
  const int height = in.U8();
  const std::string payload = in.Rest();
  std::vector<uint16_t> out;
  const omni::Status s = DecodeDepth(encoding, reinterpret_cast<const uint8_t*>(payload.data()),
                                     payload.size(), width, height, &out);
  if (s.ok()) OMNI_FUZZ_CHECK(out.size() == static_cast<size_t>(width) * height);

  // The round trip on the payload read as pixels.
  const size_t n = payload.size() / 2;
  if (n == 0) return 0;
  const int w = 1 + static_cast<int>(data[0] % 64) % static_cast<int>(n);
  const int h = static_cast<int>(n) / w;
  std::vector<uint16_t> pixels(static_cast<size_t>(w) * h);
  std::memcpy(pixels.data(), payload.data(), pixels.size() * 2);
  for (DepthEncoding enc : {DepthEncoding::kRaw, DepthEncoding::kZlib, DepthEncoding::kDeltaZlib}) {
    for (DepthPredictor p :
         {DepthPredictor::kLeft, DepthPredictor::kUp, DepthPredictor::kMed, DepthPredictor::kAvg}) {
      if (enc != DepthEncoding::kDeltaZlib && p != DepthPredictor::kMed) continue;
      DepthEncodeOptions options;
      options.predictor = p;
      std::vector<uint8_t> bytes;
      OMNI_FUZZ_CHECK(EncodeDepth(enc, pixels.data(), w, h, options, &bytes).ok());
      std::vector<uint16_t> back;
      OMNI_FUZZ_CHECK(
          DecodeDepth(static_cast<int8_t>(enc), bytes.data(), bytes.size(), w, h, &back).ok());
      OMNI_FUZZ_CHECK(back == pixels);
    }
  }
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  using namespace omni::kinect;
  const int w = 16, h = 12;
  std::vector<uint16_t> depth(w * h);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u)
      depth[v * w + u] =
          ((u * 7 + v * 3) % 23 == 0) ? 0 : static_cast<uint16_t>(800 + 12 * u + 5 * v);
  for (DepthEncoding enc : {DepthEncoding::kRaw, DepthEncoding::kZlib, DepthEncoding::kDeltaZlib}) {
    std::vector<uint8_t> bytes;
    if (!EncodeDepth(enc, depth.data(), w, h, {}, &bytes).ok()) continue;
    std::string s;
    s += static_cast<char>(enc);
    s += static_cast<char>(w);
    s += static_cast<char>(h);
    s.append(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    seeds->Add(s);
  }
}
