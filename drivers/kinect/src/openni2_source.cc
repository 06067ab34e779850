#include "omni/kinect/openni2_source.h"

#include <OpenNI.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <thread>
#include <utility>

#if defined(__SANITIZE_ADDRESS__)
#include <sanitizer/lsan_interface.h>
#endif

namespace omni::kinect {
namespace {

// OpenNI2's drivers (libPS1080, libPSLink, ...) allocate blocks at load and device-open time
// that they never free; LeakSanitizer would report them against every sanitizer run. Memory
// allocated while this is alive is not reported (no effect in normal builds).
class IgnoreOpenNILeaks {
 public:
#if defined(__SANITIZE_ADDRESS__)
  IgnoreOpenNILeaks() { __lsan_disable(); }
  ~IgnoreOpenNILeaks() { __lsan_enable(); }
#else
  IgnoreOpenNILeaks() {}
#endif
  IgnoreOpenNILeaks(const IgnoreOpenNILeaks&) = delete;
  IgnoreOpenNILeaks& operator=(const IgnoreOpenNILeaks&) = delete;
};

}  // namespace

Intrinsics IntrinsicsFromFov(int width, int height, double hfov_rad, double vfov_rad) {
  Intrinsics k;
  k.cx = (width - 1) / 2.0;
  k.cy = (height - 1) / 2.0;
  const double kPi = 3.14159265358979323846;
  if (hfov_rad > 0 && hfov_rad < kPi) k.fx = width / (2.0 * std::tan(hfov_rad / 2.0));
  if (vfov_rad > 0 && vfov_rad < kPi) k.fy = height / (2.0 * std::tan(vfov_rad / 2.0));
  return k;
}

namespace {

std::string OniError(const char* what) {
  std::string text = what;
  const char* ext = openni::OpenNI::getExtendedError();
  if (ext != nullptr && ext[0] != '\0') {
    std::string e = ext;
    while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
    size_t start = e.find_first_not_of("\t ");
    text += ": " + (start == std::string::npos ? e : e.substr(start));
  }
  return text;
}

Intrinsics StreamIntrinsics(openni::VideoStream& s, int w, int h, const OpenNI2Options& o) {
  double hfov = s.getHorizontalFieldOfView();
  double vfov = s.getVerticalFieldOfView();
  if (!(hfov > 0)) hfov = o.fallback_hfov_rad;
  if (!(vfov > 0)) vfov = o.fallback_vfov_rad;
  return IntrinsicsFromFov(w, h, hfov, vfov);
}

}  // namespace

struct OpenNI2DepthSource::Impl {
  bool initialized = false;
  bool open = false;
  bool color_open = false;
  bool registered = false;
  std::string warning;  // see DepthSource::Warning()
  openni::Device device;
  openni::VideoStream depth;
  openni::VideoStream color;
};

OpenNI2DepthSource::OpenNI2DepthSource(OpenNI2Options options)
    : options_(std::move(options)), impl_(std::make_unique<Impl>()) {}

OpenNI2DepthSource::~OpenNI2DepthSource() {
  Close();
  if (impl_->initialized) {
    const IgnoreOpenNILeaks ignore_driver_leaks;
    openni::OpenNI::shutdown();
  }
}

std::string OpenNI2DepthSource::Describe() const {
  return options_.uri.empty() ? std::string("first OpenNI2 device")
                              : "OpenNI2 device '" + options_.uri + "'";
}

std::string OpenNI2DepthSource::Warning() const { return impl_->warning; }

bool OpenNI2DepthSource::color_open() const { return impl_->color_open; }
bool OpenNI2DepthSource::registered() const { return impl_->registered; }

Status OpenNI2DepthSource::Open() {
  Close();
  const IgnoreOpenNILeaks ignore_driver_leaks;
  Impl& m = *impl_;
  if (!m.initialized) {
    if (openni::OpenNI::initialize() != openni::STATUS_OK) {
      return MakeError(ErrorCode::kUnavailable,
                       OniError("OpenNI2 initialize failed (drivers from /etc/openni2/OpenNI.ini "
                                "[Drivers] Repository)"));
    }
    m.initialized = true;
  }
  const char* uri = options_.uri.empty() ? openni::ANY_DEVICE : options_.uri.c_str();
  if (m.device.open(uri) != openni::STATUS_OK) {
    return MakeError(ErrorCode::kNotFound, OniError(("cannot open " + Describe()).c_str()));
  }
  m.open = true;
  if (m.depth.create(m.device, openni::SENSOR_DEPTH) != openni::STATUS_OK) {
    std::string e = OniError(("no depth stream on " + Describe()).c_str());
    Close();
    return MakeError(ErrorCode::kUnavailable, e);
  }
  // setVideoMode's status is not trusted either way: the mode is read back and judged.
  openni::VideoMode mode = m.depth.getVideoMode();
  if (mode.getPixelFormat() != openni::PIXEL_FORMAT_DEPTH_1_MM) {
    mode.setPixelFormat(openni::PIXEL_FORMAT_DEPTH_1_MM);
    (void)m.depth.setVideoMode(mode);
  }
  const openni::PixelFormat depth_format = m.depth.getVideoMode().getPixelFormat();
  if (depth_format != openni::PIXEL_FORMAT_DEPTH_1_MM &&
      depth_format != openni::PIXEL_FORMAT_DEPTH_100_UM) {
    // Every frame would be unusable: fail the open (retried) rather than stream nothing.
    const std::string e = Describe() + ": depth pixel format " +
                          std::to_string(static_cast<int>(depth_format)) +
                          " is not 16-bit depth and the device refuses DEPTH_1_MM";
    Close();
    return MakeError(ErrorCode::kUnavailable, e);
  }
  if (options_.color) {
    // Colour that cannot be had leaves depth running, with a warning (DepthSource::Warning).
    if (!m.device.hasSensor(openni::SENSOR_COLOR)) {
      m.warning = "colour off: the device has no colour sensor";
    } else if (m.color.create(m.device, openni::SENSOR_COLOR) != openni::STATUS_OK) {
      m.warning = OniError("colour off: cannot create the colour stream");
    } else {
      openni::VideoMode cm = m.color.getVideoMode();
      if (cm.getPixelFormat() != openni::PIXEL_FORMAT_RGB888) {
        cm.setPixelFormat(openni::PIXEL_FORMAT_RGB888);
        (void)m.color.setVideoMode(cm);
      }
      const openni::PixelFormat color_format = m.color.getVideoMode().getPixelFormat();
      if (color_format != openni::PIXEL_FORMAT_RGB888) {
        // Every colour frame would be skipped as unusable; better not to open the stream.
        m.warning = "colour off: the device gives pixel format " +
                    std::to_string(static_cast<int>(color_format)) + " and refuses RGB888";
      } else if (m.color.start() != openni::STATUS_OK) {
        m.warning = OniError("colour off: cannot start the colour stream");
      } else {
        m.color_open = true;
      }
      if (!m.color_open) m.color.destroy();
    }
  }
  if (options_.register_depth_to_color && m.color_open &&
      m.device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR)) {
    m.registered = m.device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) ==
                   openni::STATUS_OK;
  }
  if (m.depth.start() != openni::STATUS_OK) {
    std::string e = OniError(("cannot start the depth stream of " + Describe()).c_str());
    Close();
    return MakeError(ErrorCode::kUnavailable, e);
  }
  return Status::Ok();
}

void OpenNI2DepthSource::Close() {
  Impl& m = *impl_;
  const bool running = m.depth.isValid() || m.color.isValid();
  if (m.depth.isValid()) m.depth.stop();
  if (m.color.isValid()) m.color.stop();
  // stop() returns before a driver's frame thread has finished its current period (the Dummy
  // driver's thread still touches the stream then): destroying the stream at once crashes it.
  if (running) std::this_thread::sleep_for(std::chrono::milliseconds(150));
  if (m.depth.isValid()) m.depth.destroy();
  if (m.color.isValid()) m.color.destroy();
  m.color_open = false;
  m.registered = false;
  m.warning.clear();
  if (m.open) {
    m.device.close();
    m.open = false;
  }
}

Status OpenNI2DepthSource::Read(int timeout_ms, SourceFrames* out) {
  out->has_depth = false;
  out->has_color = false;
  Impl& m = *impl_;
  if (!m.open || !m.depth.isValid()) {
    return MakeError(ErrorCode::kUnavailable, Describe() + " is not open");
  }
  openni::VideoStream* streams[2] = {&m.depth, &m.color};
  const int n = m.color_open ? 2 : 1;
  int ready = -1;
  const openni::Status ws = openni::OpenNI::waitForAnyStream(streams, n, &ready, timeout_ms);
  if (ws == openni::STATUS_TIME_OUT) return Status::Ok();
  if (ws != openni::STATUS_OK) {
    return MakeError(ErrorCode::kUnavailable, OniError(("wait on " + Describe()).c_str()));
  }
  openni::VideoFrameRef f;
  if (streams[ready]->readFrame(&f) != openni::STATUS_OK || !f.isValid()) {
    return MakeError(ErrorCode::kUnavailable, OniError(("read from " + Describe()).c_str()));
  }
  const int w = f.getWidth(), h = f.getHeight(), stride = f.getStrideInBytes();
  const auto* bytes = static_cast<const uint8_t*>(f.getData());
  if (ready == 0) {
    const auto fmt = f.getVideoMode().getPixelFormat();
    if (fmt != openni::PIXEL_FORMAT_DEPTH_1_MM && fmt != openni::PIXEL_FORMAT_DEPTH_100_UM) {
      return MakeError(ErrorCode::kParse, Describe() + ": depth pixel format " +
                                              std::to_string(static_cast<int>(fmt)) +
                                              " is not 16-bit depth");
    }
    if (w <= 0 || h <= 0 || stride < w * 2 || f.getDataSize() < stride * h) {
      return MakeError(ErrorCode::kParse, Describe() + ": inconsistent depth frame size");
    }
    DepthFrame& d = out->depth;
    d.width = w;
    d.height = h;
    d.depth_mm.resize(static_cast<size_t>(w) * static_cast<size_t>(h));
    for (int v = 0; v < h; ++v) {
      std::memcpy(&d.depth_mm[static_cast<size_t>(v) * static_cast<size_t>(w)],
                  bytes + static_cast<size_t>(v) * static_cast<size_t>(stride),
                  static_cast<size_t>(w) * 2);
    }
    if (fmt == openni::PIXEL_FORMAT_DEPTH_100_UM) {
      for (uint16_t& x : d.depth_mm) x = static_cast<uint16_t>(x / 10);
    }
    d.intrinsics = StreamIntrinsics(m.depth, w, h, options_);
    d.device_timestamp_us = static_cast<int64_t>(f.getTimestamp());
    d.frame_index = f.getFrameIndex();
    d.registered_to_color = m.registered;
    // Registered depth is resampled into the colour camera's view: its intrinsics apply.
    if (m.registered) d.intrinsics = StreamIntrinsics(m.color, w, h, options_);
    out->has_depth = true;
  } else {
    if (f.getVideoMode().getPixelFormat() != openni::PIXEL_FORMAT_RGB888 || w <= 0 || h <= 0 ||
        stride < w * 3 || f.getDataSize() < stride * h) {
      return MakeError(ErrorCode::kParse, Describe() + ": colour frame is not RGB888");
    }
    ColorFrame& c = out->color;
    c.width = w;
    c.height = h;
    c.rgb.resize(static_cast<size_t>(w) * static_cast<size_t>(h) * 3);
    for (int v = 0; v < h; ++v) {
      std::memcpy(&c.rgb[static_cast<size_t>(v) * static_cast<size_t>(w) * 3],
                  bytes + static_cast<size_t>(v) * static_cast<size_t>(stride),
                  static_cast<size_t>(w) * 3);
    }
    c.intrinsics = StreamIntrinsics(m.color, w, h, options_);
    c.device_timestamp_us = static_cast<int64_t>(f.getTimestamp());
    c.frame_index = f.getFrameIndex();
    out->has_color = true;
  }
  return Status::Ok();
}

}  // namespace omni::kinect
