#include "omni/io/carmen.h"

#include <cmath>
#include <cstdlib>
#include <limits>
#include <sstream>

#include <zlib.h>

namespace omni::io {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

// Splits on whitespace.
std::vector<std::string> Tokens(const std::string& line) {
  std::vector<std::string> out;
  std::istringstream ss(line);
  std::string t;
  while (ss >> t) out.push_back(t);
  return out;
}

bool ToDouble(const std::string& s, double* v) {
  if (s.empty()) return false;
  char* end = nullptr;
  *v = std::strtod(s.c_str(), &end);
  return end == s.c_str() + s.size();
}

class LineParser {
 public:
  LineParser(const std::vector<std::string>& tok, const std::string& where)
      : tok_(tok), where_(where) {}
  bool Number(const char* what, double* v) {
    if (i_ >= tok_.size()) return Fail(std::string("line ends before ") + what);
    if (!ToDouble(tok_[i_], v))
      return Fail(std::string("'") + tok_[i_] + "' is not a number (" + what + ")");
    ++i_;
    return true;
  }
  // A number that must be finite: poses, angles, ranges' limits (a NaN there is a corrupt
  // line, not a reading to count downstream) and no larger than `limit` in magnitude.
  bool Finite(const char* what, double* v, double limit = 1e15) {
    if (!Number(what, v)) return false;
    if (!std::isfinite(*v) || std::fabs(*v) > limit) {
      --i_;
      return Fail(std::string("'") + tok_[i_] + "' is not a finite number within +-" +
                  Short(limit) + " (" + what + ")");
    }
    return true;
  }
  // A time stamp in seconds: finite and within +-73,000 years (what microseconds in an int64
  // can hold with room for sums), so converting it to a stamp is defined.
  bool Stamp(const char* what, double* v) { return Finite(what, v, 2.3e12); }
  bool Skip(const char* what) {
    if (i_ >= tok_.size()) return Fail(std::string("line ends before ") + what);
    ++i_;
    return true;
  }
  size_t remaining() const { return tok_.size() - i_; }
  static std::string Short(double v) {
    std::ostringstream ss;
    ss << v;
    return ss.str();
  }
  const std::string& error() const { return error_; }

 private:
  bool Fail(const std::string& why) {
    error_ = where_ + ": " + why;
    return false;
  }
  const std::vector<std::string>& tok_;
  std::string where_;
  size_t i_ = 1;  // token 0 is the tag
  std::string error_;
};

// A range reading as float: NaN and infinities pass (the mappers count them as invalid beams),
// and so does a finite value too large for a float, as an infinity (the plain conversion of
// such a value is undefined behaviour).
float RangeToFloat(double v) {
  if (std::isfinite(v) && std::fabs(v) > std::numeric_limits<float>::max())
    return v > 0 ? std::numeric_limits<float>::infinity() : -std::numeric_limits<float>::infinity();
  return static_cast<float>(v);
}

bool ParseCount(LineParser& p, const char* what, size_t* n) {
  double v = 0;
  if (!p.Number(what, &v)) return false;
  if (v < 0 || v > 100000 || v != std::floor(v)) return false;
  *n = static_cast<size_t>(v);
  return true;
}

}  // namespace

float CarmenBeamIncrementRad(size_t n) {
  if (n == 180 || n == 181) return static_cast<float>(1.0 * kDegToRad);
  if (n == 360 || n == 361) return static_cast<float>(0.5 * kDegToRad);
  if (n <= 1) return 0.f;
  return static_cast<float>(M_PI / static_cast<double>(n - 1));
}

Result<std::string> ReadMaybeGzipFile(const std::string& path) {
  gzFile f = gzopen(path.c_str(), "rb");
  if (!f) return MakeError(ErrorCode::kNotFound, "cannot open '" + path + "'");
  std::string out;
  char buf[1 << 16];
  for (;;) {
    const int n = gzread(f, buf, sizeof(buf));
    if (n < 0) {
      int errnum = 0;
      std::string msg = gzerror(f, &errnum);
      gzclose(f);
      return MakeError(ErrorCode::kIo, "'" + path + "': decompression failed after " +
                                           std::to_string(out.size()) + " bytes: " + msg);
    }
    if (n == 0) {
      // A .gz cut short (a copy or download stopped) reads as an end of file; zlib says so only
      // here. Without this check the log would be imported short, or fail on its last line
      // with an error that blames the line.
      int errnum = 0;
      gzerror(f, &errnum);
      gzclose(f);
      if (errnum == Z_BUF_ERROR)
        return MakeError(ErrorCode::kIo, "'" + path +
                                             "': the compressed data ends early (a truncated "
                                             ".gz file?) after " +
                                             std::to_string(out.size()) + " bytes");
      return out;
    }
    out.append(buf, static_cast<size_t>(n));
  }
}

namespace {

// FLASER/RLASER lines do not say the sensor's range. CARMEN writes a beam without a return as
// that range, so it is the value most lines share as their largest reading (30 m on intel.clf,
// 50 m on ACES, 81.91 m on Freiburg 079: on about half the lines). A line's own largest reading
// is not it: on a line where every beam returned, that is its farthest real return, which would
// then be read as "no return". A log where no largest reading recurs on at least 5 % of the
// lines takes its overall largest reading.
void SetSensorMaxRange(CarmenLog* log) {
  for (const char* tag : {"FLASER", "RLASER"}) {
    std::map<float, size_t> line_max;
    size_t lines = 0;
    float overall = 0.f;
    for (const CarmenRecord& r : log->records) {
      if (r.kind != CarmenRecord::Kind::kLaser || r.laser.tag != tag) continue;
      ++lines;
      ++line_max[r.laser.max_range_m];
      overall = std::max(overall, r.laser.max_range_m);
    }
    if (lines == 0) continue;
    float mode = overall;
    size_t mode_lines = 0;
    for (const auto& [value, count] : line_max) {
      if (count > mode_lines || (count == mode_lines && value > mode)) {
        mode = value;
        mode_lines = count;
      }
    }
    const float sensor_max = mode_lines * 20 >= lines && mode_lines >= 1 ? mode : overall;
    log->max_range_m[tag] = sensor_max;
    for (CarmenRecord& r : log->records)
      if (r.kind == CarmenRecord::Kind::kLaser && r.laser.tag == tag)
        r.laser.max_range_m = sensor_max;
  }
}

}  // namespace

Result<CarmenLog> ReadCarmenLog(const std::string& path) {
  auto text = ReadMaybeGzipFile(path);
  if (!text.ok()) return text.error();
  std::istringstream in(*text);
  return ParseCarmenLog(in, path);
}

Result<CarmenLog> ParseCarmenLog(std::istream& in, const std::string& name) {
  CarmenLog log;
  std::string line;
  int64_t lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const auto tok = Tokens(line);
    if (tok.empty() || tok[0][0] == '#') continue;
    const std::string& tag = tok[0];
    const std::string where = name + ":" + std::to_string(lineno);
    LineParser p(tok, where);
    auto fail = [&](const std::string& why) -> Error {
      return MakeError(ErrorCode::kParse,
                       p.error().empty() ? where + ": " + why : p.error() + " (" + tag + ")");
    };
    if (tag == "ODOM") {
      CarmenRecord r;
      r.kind = CarmenRecord::Kind::kOdom;
      r.odom.line = lineno;
      double accel = 0;
      if (!p.Finite("x", &r.odom.pose.x) || !p.Finite("y", &r.odom.pose.y) ||
          !p.Finite("theta", &r.odom.pose.theta) || !p.Number("tv", &r.odom.tv_m_s) ||
          !p.Number("rv", &r.odom.rv_rad_s) || !p.Number("accel", &accel) ||
          !p.Stamp("ipc_timestamp", &r.odom.timestamp_s) || !p.Skip("ipc_hostname") ||
          !p.Skip("logger_timestamp")) {
        return fail("malformed ODOM line");
      }
      log.records.push_back(std::move(r));
      ++log.num_odometry;
    } else if (tag == "FLASER" || tag == "RLASER") {
      CarmenRecord r;
      r.kind = CarmenRecord::Kind::kLaser;
      CarmenLaser& l = r.laser;
      l.tag = tag;
      l.line = lineno;
      size_t n = 0;
      if (!ParseCount(p, "num_readings", &n)) return fail("bad beam count");
      l.ranges_m.resize(n);
      float max_r = 0.f;
      for (size_t i = 0; i < n; ++i) {
        double v = 0;
        if (!p.Number("a range reading", &v)) return fail("truncated ranges");
        l.ranges_m[i] = RangeToFloat(v);
        if (std::isfinite(l.ranges_m[i])) max_r = std::max(max_r, l.ranges_m[i]);
      }
      if (!p.Finite("x", &l.laser_pose.x) || !p.Finite("y", &l.laser_pose.y) ||
          !p.Finite("theta", &l.laser_pose.theta) || !p.Finite("odom_x", &l.robot_pose.x) ||
          !p.Finite("odom_y", &l.robot_pose.y) || !p.Finite("odom_theta", &l.robot_pose.theta) ||
          !p.Stamp("ipc_timestamp", &l.timestamp_s) || !p.Skip("ipc_hostname") ||
          !p.Skip("logger_timestamp")) {
        return fail("malformed laser line");
      }
      l.angle_increment_rad = CarmenBeamIncrementRad(n);
      l.angle_min_rad = static_cast<float>(-M_PI / 2);
      l.max_range_m = max_r;  // this line's own; replaced by the log's below
      log.records.push_back(std::move(r));
      ++log.num_lasers;
    } else if (tag == "ROBOTLASER1") {
      CarmenRecord r;
      r.kind = CarmenRecord::Kind::kLaser;
      CarmenLaser& l = r.laser;
      l.tag = tag;
      l.line = lineno;
      double laser_type, start, fov, res, max_range, accuracy, remission_mode;
      if (!p.Number("laser_type", &laser_type) || !p.Finite("start_angle", &start, 1e3) ||
          !p.Number("field_of_view", &fov) || !p.Finite("angular_resolution", &res, 1e3) ||
          !p.Finite("maximum_range", &max_range, 1e9) || !p.Number("accuracy", &accuracy) ||
          !p.Number("remission_mode", &remission_mode)) {
        return fail("malformed ROBOTLASER1 header");
      }
      size_t n = 0;
      if (!ParseCount(p, "num_readings", &n)) return fail("bad beam count");
      l.ranges_m.resize(n);
      for (size_t i = 0; i < n; ++i) {
        double v = 0;
        if (!p.Number("a range reading", &v)) return fail("truncated ranges");
        l.ranges_m[i] = RangeToFloat(v);
      }
      size_t nrem = 0;
      if (!ParseCount(p, "num_remissions", &nrem)) return fail("bad remission count");
      for (size_t i = 0; i < nrem; ++i)
        if (!p.Skip("a remission value")) return fail("truncated remissions");
      double tv, rv, fsd, ssd, turn;
      if (!p.Finite("laser_pose_x", &l.laser_pose.x) ||
          !p.Finite("laser_pose_y", &l.laser_pose.y) ||
          !p.Finite("laser_pose_theta", &l.laser_pose.theta) ||
          !p.Finite("robot_pose_x", &l.robot_pose.x) ||
          !p.Finite("robot_pose_y", &l.robot_pose.y) ||
          !p.Finite("robot_pose_theta", &l.robot_pose.theta) || !p.Number("laser_tv", &tv) ||
          !p.Number("laser_rv", &rv) || !p.Number("forward_safety_dist", &fsd) ||
          !p.Number("side_safety_dist", &ssd) || !p.Number("turn_axis", &turn) ||
          !p.Stamp("timestamp", &l.timestamp_s) || !p.Skip("hostname") ||
          !p.Skip("logger_timestamp")) {
        return fail("malformed ROBOTLASER1 line");
      }
      l.angle_min_rad = static_cast<float>(start);
      l.angle_increment_rad = static_cast<float>(res);
      l.max_range_m = static_cast<float>(max_range);
      log.records.push_back(std::move(r));
      ++log.num_lasers;
    } else {
      ++log.skipped[tag];
    }
  }
  SetSensorMaxRange(&log);
  return log;
}

}  // namespace omni::io
