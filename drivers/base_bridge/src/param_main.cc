// omni-base-param (./omni base-param): reads and writes the base firmware's parameters over CAN
// (GET_PARAM / SET_PARAM) and keeps them across power cycles (SAVE_PARAMS, the firmware's
// parameter store). It is one more node on the bus, beside the base bridge (SocketCAN and the
// shm: bus both let several processes share an interface).
//
//   omni-base-param --can URL [--node N] list
//   omni-base-param --can URL get NAME|ID
//   omni-base-param --can URL set NAME|ID VALUE
//   omni-base-param --can URL save | erase | status
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "omni/can/can_bus.h"
#include "omni/common/cli.h"
#include "omni/firmware/can_protocol.h"
#include "omni/firmware/param_store.h"
#include "omni/firmware/params.h"

namespace {

namespace fw = omni::firmware;
namespace fwcan = omni::firmware::can;

// The names of docs/firmware.md's parameter table (ids are the protocol's, fw::ParamId).
struct Named {
  uint16_t id;
  const char* name;
};
constexpr Named kParams[] = {
    {fw::kParamKp, "kp"},
    {fw::kParamKi, "ki"},
    {fw::kParamKd, "kd"},
    {fw::kParamKff, "kff"},
    {fw::kParamMaxDuty, "max_duty"},
    {fw::kParamMaxWheelSpeed, "max_wheel_speed_rad_s"},
    {fw::kParamMaxWheelAccel, "max_wheel_accel_rad_s2"},
    {fw::kParamStopDecel, "stop_decel_rad_s2"},
    {fw::kParamWatchdogMs, "watchdog_ms"},
    {fw::kParamCurrentLimit, "current_limit_a"},
    {fw::kParamOverCurrentMs, "over_current_ms"},
    {fw::kParamUnderVoltage, "under_voltage_v"},
    {fw::kParamUnderVoltageMs, "under_voltage_ms"},
    {fw::kParamStallMs, "stall_ms"},
    {fw::kParamStallDuty, "stall_duty"},
    {fw::kParamAlpha, "alpha_rad"},
    {fw::kParamCenterToWheel, "center_to_wheel_m"},
    {fw::kParamWheelRadius, "wheel_radius_m"},
    {fw::kParamTicksPerRev, "ticks_per_rev"},
    {fw::kParamFeedbackPeriodMs, "feedback_period_ms"},
    {fw::kParamHeartbeatPeriodMs, "heartbeat_period_ms"},
    {fw::kParamControlPeriodUs, "control_period_us"},
    {fw::kParamFirmwareVersion, "firmware_version"},
};

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-base-param --can URL [--node N] [--timeout S] COMMAND\n"
      "  list                  every parameter's value\n"
      "  get NAME|ID           one parameter\n"
      "  set NAME|ID VALUE     write one (the firmware refuses values out of range)\n"
      "  save                  keep the current parameters across power cycles (motors must\n"
      "                        be off: IDLE, FAULT or ESTOP; the board stalls ~0.5 s writing)\n"
      "  erase                 forget them: the next boot uses the compiled defaults\n"
      "  status                what the parameter store holds\n"
      "  URL: socketcan:IF (the robot) or shm:NAME (omni-firmware-sim); N: the firmware's CAN\n"
      "  node (default 1). Exit status 0 done, 1 refused or no answer, 2 bad command line.\n");
}

const char* NameOf(uint16_t id) {
  for (const auto& p : kParams)
    if (p.id == id) return p.name;
  return "?";
}

class Client {
 public:
  Client(omni::can::CanBus* bus, uint8_t node, double timeout_s)
      : bus_(bus), node_(node), timeout_s_(timeout_s) {}

  // Sends `f` and waits for the firmware's frame of command `reply` (and, for parameter
  // replies, the same id and the answer to the same kind of request: a SET's answer is marked,
  // so the answer to another client's GET is not taken for it); false on timeout or a bus error
  // (said on stderr).
  bool Ask(const fw::CanFrame& f, uint8_t reply, uint16_t param_id, fw::CanFrame* out,
           bool of_set = false) {
    omni::can::Frame c;
    c.id = f.id;
    c.dlc = f.dlc;
    for (int i = 0; i < 8; ++i) c.data[i] = f.data[i];
    if (omni::Status s = bus_->Send(c); !s.ok()) {
      std::fprintf(stderr, "omni-base-param: %s\n", s.message().c_str());
      return false;
    }
    const auto deadline = std::chrono::steady_clock::now() +
                          std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                              std::chrono::duration<double>(timeout_s_));
    while (std::chrono::steady_clock::now() < deadline) {
      omni::can::Frame r;
      auto got = bus_->Receive(&r, 20);
      if (!got.ok()) {
        std::fprintf(stderr, "omni-base-param: %s\n", got.error().message.c_str());
        return false;
      }
      if (!*got || r.extended || r.id != fwcan::MakeId(node_, reply)) continue;
      out->id = static_cast<uint16_t>(r.id);
      out->dlc = r.dlc;
      for (int i = 0; i < 8; ++i) out->data[i] = r.data[i];
      if (reply == fwcan::kParamValue) {
        fwcan::ParamReply p;
        if (!fwcan::DecodeParamReply(*out, &p) || p.id != param_id || (p.of_set != 0) != of_set)
          continue;
      }
      return true;
    }
    std::fprintf(stderr, "omni-base-param: no answer from node %d within %g s (is the base on?)\n",
                 node_, timeout_s_);
    return false;
  }

  bool Param(bool set, uint16_t id, float value, fwcan::ParamReply* reply) {
    fw::CanFrame f;
    if (set) {
      fwcan::ParamRequest req;
      req.id = id;
      req.value = value;
      f = fwcan::EncodeSetParam(node_, req);
    } else {
      f = fwcan::EncodeGetParam(node_, id);
    }
    fw::CanFrame r;
    return Ask(f, fwcan::kParamValue, id, &r, set) && fwcan::DecodeParamReply(r, reply);
  }

  bool Store(uint8_t action, fwcan::ParamStoreStatus* st) {
    fw::CanFrame r;
    return Ask(fwcan::EncodeSaveParams(node_, action), fwcan::kParamStoreStatus, 0, &r) &&
           fwcan::DecodeParamStoreStatus(r, st);
  }

 private:
  omni::can::CanBus* bus_;
  uint8_t node_;
  double timeout_s_;
};

const char* ResultText(uint8_t r) {
  switch (r) {
    case fwcan::kParamOk:
      return "ok";
    case fwcan::kParamUnknown:
      return "unknown parameter";
    case fwcan::kParamOutOfRange:
      return "refused: out of range";
    case fwcan::kParamReadOnly:
      return "refused: read-only";
    default:
      return "refused";
  }
}

int PrintStore(const fwcan::ParamStoreStatus& st) {
  static const char* kBoot[] = {"empty (compiled defaults)", "loaded",
                                "corrupt (compiled defaults)", "no store on this board"};
  static const char* kResult[] = {"ok", "refused: the motors are not off", "write failed",
                                  "this board has no parameter store", "bad action"};
  std::printf("result: %s\nat boot: %s\nstored now: %d parameters (crc %08x)\n",
              st.result < 5 ? kResult[st.result] : "?",
              st.boot_state < 4 ? kBoot[st.boot_state] : "?", st.stored,
              static_cast<unsigned>(st.crc));
  return st.result == fwcan::kStoreOk ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  std::string url;
  int64_t node = 1;
  double timeout_s = 1.0;
  std::vector<std::string> words;
  omni::ArgReader args(argc, argv, "omni-base-param", Usage);
  while (args.Next()) {
    if (args.Is("--can")) {
      url = args.Value();
    } else if (args.Is("--node")) {
      node = args.Integer(0, 63);
    } else if (args.Is("--timeout")) {
      timeout_s = args.Number(0.05, 60);
    } else if (!args.arg().empty() &&
               (args.arg()[0] != '-' ||
                // A negative number is a value (`set NAME -0.5`), not an option.
                (words.size() == 2 && words[0] == "set" && args.arg().size() > 1 &&
                 (std::isdigit(static_cast<unsigned char>(args.arg()[1])) ||
                  args.arg()[1] == '.')))) {
      words.push_back(args.arg());
    } else {
      args.Unknown();
    }
  }
  if (url.empty()) args.Fail("--can URL is required (socketcan:can0, or shm:NAME for the sim)");
  if (words.empty()) args.Fail("which command? list, get, set, save, erase or status");
  const std::string cmd = words[0];
  auto param_id = [&](const std::string& w) -> uint16_t {
    for (const auto& p : kParams)
      if (w == p.name) return p.id;
    char* end = nullptr;
    const long v = std::strtol(w.c_str(), &end, 10);
    if (!w.empty() && *end == '\0' && v > 0 && v < 65536) return static_cast<uint16_t>(v);
    args.Fail("no parameter named '" + w + "' (omni-base-param --help; list shows them all)");
  };
  const size_t want = cmd == "get" ? 2 : cmd == "set" ? 3 : 1;
  if (cmd != "list" && cmd != "get" && cmd != "set" && cmd != "save" && cmd != "erase" &&
      cmd != "status")
    args.Fail("unknown command '" + cmd + "'");
  if (words.size() != want) args.Fail(cmd + " takes " + std::to_string(want - 1) + " argument(s)");
  float value = 0.f;
  if (cmd == "set") {
    char* end = nullptr;
    value = std::strtof(words[2].c_str(), &end);
    if (words[2].empty() || *end != '\0' || !std::isfinite(value))
      args.Fail("set expects a number, got '" + words[2] + "'");
  }

  auto bus = omni::can::OpenCanBus(url);
  if (!bus.ok()) {
    std::fprintf(stderr, "omni-base-param: %s\n", bus.error().message.c_str());
    return 1;
  }
  Client client(bus->get(), static_cast<uint8_t>(node),
                cmd == "save" || cmd == "erase" ? std::max(timeout_s, 3.0) : timeout_s);
  if (cmd == "list") {
    int failed = 0;
    for (const auto& p : kParams) {
      fwcan::ParamReply r;
      if (!client.Param(false, p.id, 0.f, &r)) return 1;
      if (r.result == fwcan::kParamOk)
        std::printf("%-24s %3d  %g\n", p.name, p.id, static_cast<double>(r.value));
      else
        std::printf("%-24s %3d  (%s)\n", p.name, p.id, ResultText(r.result)), ++failed;
    }
    return failed > 0 ? 1 : 0;
  }
  if (cmd == "get" || cmd == "set") {
    const uint16_t id = param_id(words[1]);
    fwcan::ParamReply r;
    if (!client.Param(cmd == "set", id, value, &r)) return 1;
    std::printf("%s (%d) = %g%s%s\n", NameOf(id), id, static_cast<double>(r.value),
                r.result == fwcan::kParamOk ? "" : "  ",
                r.result == fwcan::kParamOk ? "" : ResultText(r.result));
    if (r.result == fwcan::kParamOk && cmd == "set")
      std::printf("(until the next power cycle; `save` keeps it)\n");
    return r.result == fwcan::kParamOk ? 0 : 1;
  }
  const uint8_t action = cmd == "save"    ? fwcan::kStoreSave
                         : cmd == "erase" ? fwcan::kStoreErase
                                          : fwcan::kStoreQuery;
  fwcan::ParamStoreStatus st;
  if (!client.Store(action, &st)) return 1;
  return PrintStore(st);
}
