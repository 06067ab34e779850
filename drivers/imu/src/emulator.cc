#include "omni/imu/emulator.h"

#include <unistd.h>

#include <cmath>
#include <random>

#include "omni/imu/witmotion.h"
#include "omni/serial/serial_port.h"

namespace omni::imu {
namespace {

int16_t Quat(double q) {
  const long r = std::lround(q * 32768.0);
  return static_cast<int16_t>(r > 32767 ? 32767 : (r < -32768 ? -32768 : r));
}

int16_t Raw(double v) {
  const long r = std::lround(v);
  return static_cast<int16_t>(r > 32767 ? 32767 : (r < -32768 ? -32768 : r));
}

bool ValidFrame(const uint8_t* p) {
  if (p[0] != kHeader || !IsKnownType(p[1])) return false;
  unsigned sum = 0;
  for (size_t i = 0; i < 10; ++i) sum += p[i];
  return (sum & 0xFF) == p[10];
}

}  // namespace

MotionState SimulatedMotion(const EmulatorOptions& o, double t_s) {
  MotionState m;
  const double phi = o.roll_rad, theta = o.pitch_rad;
  const double yaw = o.yaw0_rad + o.yaw_rate_rad_s * t_s;
  const double sp = std::sin(phi), cp = std::cos(phi), st = std::sin(theta), ct = std::cos(theta);
  // R = Rz(yaw) Ry(pitch) Rx(roll) maps body to world; the body sees R^T of world vectors.
  m.accel_m_s2 = {-kGravity * st, kGravity * ct * sp, kGravity * ct * cp};
  const double w = o.yaw_rate_rad_s;  // about world z: R^T (0, 0, w)
  m.gyro_rad_s = {-w * st, w * ct * sp, w * ct * cp};
  m.euler_rad = {phi, theta, std::remainder(yaw, 2 * M_PI)};
  m.orientation_wxyz = EulerToQuaternion(phi, theta, yaw);
  // World field (ENU): 300 LSB north (y), 400 LSB down.
  const double cy = std::cos(yaw), sy = std::sin(yaw);
  const double wx = 0, wy = 300, wz = -400;
  // R^T v = Rx^T Ry^T Rz^T v.
  const double x1 = cy * wx + sy * wy, y1 = -sy * wx + cy * wy, z1 = wz;
  const double x2 = ct * x1 - st * z1, z2 = st * x1 + ct * z1;
  m.mag_raw = {x2, cp * y1 + sp * z2, -sp * y1 + cp * z2};
  return m;
}

std::vector<uint8_t> EncodePeriod(const EmulatorOptions& o, const MotionState& m) {
  const int16_t temp = Raw(o.temperature_c * 100.0);
  std::vector<std::array<uint8_t, kFrameSize>> frames;
  if (o.send_time) {
    // 26-12-05 00:00:00.000 (year, month, day, hour, minute, second, ms low, ms high bytes).
    frames.push_back(EncodeFrame(
        kTypeTime, {static_cast<int16_t>(26 | 12 << 8), static_cast<int16_t>(5), 0, 0}));
  }
  if (o.send_accel) {
    frames.push_back(
        EncodeFrame(kTypeAccel, {Ms2ToAccel(m.accel_m_s2[0]), Ms2ToAccel(m.accel_m_s2[1]),
                                 Ms2ToAccel(m.accel_m_s2[2]), temp}));
  }
  if (o.send_gyro) {
    frames.push_back(
        EncodeFrame(kTypeGyro, {RadSToGyro(m.gyro_rad_s[0]), RadSToGyro(m.gyro_rad_s[1]),
                                RadSToGyro(m.gyro_rad_s[2]), temp}));
  }
  if (o.send_angle) {
    frames.push_back(
        EncodeFrame(kTypeAngle, {RadToAngle(m.euler_rad[0]), RadToAngle(m.euler_rad[1]),
                                 RadToAngle(m.euler_rad[2]), temp}));
  }
  if (o.send_mag) {
    frames.push_back(
        EncodeFrame(kTypeMag, {Raw(m.mag_raw[0]), Raw(m.mag_raw[1]), Raw(m.mag_raw[2]), temp}));
  }
  if (o.send_quaternion) {
    // The sensor's sign convention: w >= 0.
    const double s = m.orientation_wxyz[0] < 0 ? -1.0 : 1.0;
    frames.push_back(EncodeFrame(
        kTypeQuaternion, {Quat(s * m.orientation_wxyz[0]), Quat(s * m.orientation_wxyz[1]),
                          Quat(s * m.orientation_wxyz[2]), Quat(s * m.orientation_wxyz[3])}));
  }
  std::vector<uint8_t> out;
  for (const auto& f : frames) out.insert(out.end(), f.begin(), f.end());
  return out;
}

Result<std::unique_ptr<ImuEmulator>> ImuEmulator::Create(EmulatorOptions options) {
  if (!(options.rate_hz > 0 && options.rate_hz <= 1000)) {
    return MakeError(ErrorCode::kInvalidArgument, "IMU emulator: rate_hz must be in (0, 1000]");
  }
  if (options.baud != 0 && !BaudCode(options.baud)) {
    return MakeError(ErrorCode::kInvalidArgument,
                     "IMU emulator: baud must be 0 (any) or a WitMotion rate 4800 ... 921600");
  }
  std::unique_ptr<ImuEmulator> e(new ImuEmulator(std::move(options)));
  e->saved_ = e->options_;
  Status st = e->Restore();
  if (!st.ok()) return st.error();
  return e;
}

void ImuEmulator::Vanish() { pty_.reset(); }

Status ImuEmulator::Restore() {
  if (pty_ == nullptr && started_) {
    // Plugged back in after an unplug: powered up with the saved settings.
    RestartPeriods();
    const std::string link = options_.link_path;
    options_ = saved_;
    options_.link_path = link;
    unlocked_ = false;
    writes_ = WriteParser();
  }
  auto pty = serial::Pty::Create(options_.link_path);
  if (!pty.ok()) return pty.error();
  pty_ = std::move(*pty);
  if (options_.link_path.empty()) options_.link_path = pty_->slave_path();
  return Status::Ok();
}

void ImuEmulator::Send(const uint8_t* data, size_t size) {
  if (!pty_) return;
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(pty_->master_fd(), data + done, size - done);
    if (n <= 0) break;  // buffer full (nobody reading): the bytes are lost, as on a real UART
    done += static_cast<size_t>(n);
  }
  counters_.bytes_streamed += static_cast<int64_t>(done);
  counters_.bytes_dropped += static_cast<int64_t>(size - done);
}

bool ImuEmulator::LineMatches() const {
  return options_.baud == 0 || (pty_ && serial::LineBaud(pty_->master_fd()) == options_.baud);
}

void ImuEmulator::RestartPeriods() {
  // Keep the motion continuous: the next period's time becomes the new origin.
  if (started_) {
    t0_s_ += static_cast<double>(next_period_) / options_.rate_hz;
    restart_pending_ = true;
  }
  next_period_ = 0;
}

void ImuEmulator::DrainInput(int64_t now_us) {
  if (!pty_) return;
  uint8_t buf[256];
  ssize_t n;
  std::vector<RegisterWrite> writes;
  while ((n = ::read(pty_->master_fd(), buf, sizeof(buf))) > 0) {
    if (!LineMatches()) {
      counters_.bytes_garbled += n;  // framing errors: nothing of it is understood
      continue;
    }
    writes_.Feed(buf, static_cast<size_t>(n), &writes);
  }
  for (const RegisterWrite& w : writes) Apply(w, now_us);
}

void ImuEmulator::Apply(const RegisterWrite& w, int64_t now_us) {
  if (unlocked_ && now_us > unlocked_until_us_) unlocked_ = false;
  auto ignore = [this] { ++counters_.writes_ignored; };
  if (!options_.accept_writes) return ignore();
  if (w.reg == kRegKey) {
    if (w.value != kUnlockKey) return ignore();
    unlocked_ = true;
    unlocked_until_us_ = now_us + 10'000'000;  // the key holds for a while, as on the device
    ++counters_.writes;
    return;
  }
  if (!unlocked_) return ignore();
  switch (w.reg) {
    case kRegSave:
      if (w.value != 0) return ignore();
      saved_ = options_;
      ++counters_.saves;
      break;
    case kRegOutputs:
      options_.send_time = (w.value & OutputBit(kTypeTime)) != 0;
      options_.send_accel = (w.value & OutputBit(kTypeAccel)) != 0;
      options_.send_gyro = (w.value & OutputBit(kTypeGyro)) != 0;
      options_.send_angle = (w.value & OutputBit(kTypeAngle)) != 0;
      options_.send_mag = (w.value & OutputBit(kTypeMag)) != 0;
      options_.send_quaternion = (w.value & OutputBit(kTypeQuaternion)) != 0;
      break;
    case kRegRate: {
      const double hz = RateOfCode(static_cast<uint8_t>(w.value));
      if (hz <= 0) return ignore();
      RestartPeriods();
      options_.rate_hz = hz;
      break;
    }
    case kRegBaud: {
      const int baud = BaudOfCode(static_cast<uint8_t>(w.value));
      if (baud == 0) return ignore();
      options_.baud = baud;  // at once: the next bytes go out at the new rate
      break;
    }
    default:
      return ignore();
  }
  ++counters_.writes;
}

void ImuEmulator::InjectGarbage(size_t bytes, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> g(bytes);
  for (auto& b : g) b = static_cast<uint8_t>(rng());
  if (!streaming_ || !pty_) {
    Send(g.data(), g.size());
    return;
  }
  garbage_.insert(garbage_.end(), g.begin(), g.end());
  garbage_seed_ = seed;
}

void ImuEmulator::Step(int64_t now_us) {
  if (!started_) {
    started_ = true;
    start_us_ = now_us;
  }
  DrainInput(now_us);
  if (restart_pending_) {
    restart_pending_ = false;
    start_us_ = now_us;
  }
  const double elapsed_s = static_cast<double>(now_us - start_us_) * 1e-6;
  const int64_t due = static_cast<int64_t>(std::floor(elapsed_s * options_.rate_hz)) + 1;
  if (!pty_ || !streaming_) {
    next_period_ = due;  // the device keeps moving while nobody hears it
    return;
  }
  std::vector<uint8_t> out;
  for (; next_period_ < due; ++next_period_) {
    const double t = t0_s_ + static_cast<double>(next_period_) / options_.rate_hz;
    std::vector<uint8_t> period = EncodePeriod(options_, SimulatedMotion(options_, t));
    const size_t nframes = period.size() / kFrameSize;
    if (!garbage_.empty() && nframes > 0) {
      // Cut one frame of this period after 1..10 bytes and put the garbage in the cut.
      std::mt19937 rng(garbage_seed_ ^ static_cast<uint32_t>(next_period_));
      const size_t frame = rng() % nframes;
      const size_t at = frame * kFrameSize + 1 + rng() % (kFrameSize - 1);
      period.insert(period.begin() + static_cast<std::ptrdiff_t>(at), garbage_.begin(),
                    garbage_.end());
      // A random byte may complete the checksum by chance: then the frame is not broken.
      // Change the first garbage byte (a payload or checksum byte of the cut frame) if so.
      if (ValidFrame(&period[frame * kFrameSize])) period[at] ^= 0xFF;
      garbage_.clear();
      ++counters_.frames_corrupted;
    }
    out.insert(out.end(), period.begin(), period.end());
    ++counters_.periods;
    counters_.frames += static_cast<int64_t>(nframes);
  }
  if (!out.empty() && !LineMatches()) {
    // The reader's UART samples at another rate: framing errors and stray bits. Mangle every
    // byte so that no 0x55 header survives (a real mismatch may decode a few by chance).
    for (uint8_t& b : out) b = static_cast<uint8_t>((b & 0x0F) | 0x80);
    counters_.bytes_garbled += static_cast<int64_t>(out.size());
  }
  if (!out.empty()) Send(out.data(), out.size());
}

}  // namespace omni::imu
