// The Cortex-M4 image: no heap, no exception handling, within the flash/RAM budget.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>
#include <string>

namespace {

const std::string kElf = OMNI_FIRMWARE_ARM_ELF;

std::set<std::string> Symbols() {
  std::set<std::string> out;

  const std::string all = "arm-none-eabi-nm '" + kElf + "' 2>&1";
  FILE* p = popen(all.c_str(), "r");
  if (p == nullptr) return out;
  char line[512];
  while (std::fgets(line, sizeof(line), p) != nullptr) {
    std::istringstream s(line);
    std::string a, b, c;
    s >> a >> b >> c;
    out.insert(c.empty() ? b : c);  // "addr type name" or "U name"
  }
  pclose(p);
  return out;
}

TEST(FirmwareArmTest, NoHeapNoExceptions) {
  if (kElf.empty()) GTEST_SKIP() << "ARM build disabled (OMNI_BUILD_FIRMWARE_ARM=OFF)";
  ASSERT_TRUE(std::ifstream(kElf).good()) << kElf << " missing: build target firmware_stm32f4";
  const std::set<std::string> syms = Symbols();
  ASSERT_GT(syms.size(), 20u) << "arm-none-eabi-nm gave nothing for " << kElf;
  EXPECT_TRUE(syms.count("Reset_Handler"));
  for (const char* bad : {"malloc",
                          "free",
                          "calloc",
                          "realloc",
                          "_malloc_r",
                          "_free_r",
                          "_sbrk",
                          "_sbrk_r",
                          "_Znwj",
                          "_Znaj",
                          "_ZdlPv",
                          "_ZdlPvj",
                          "_ZdaPv",
                          "__cxa_throw",
                          "__cxa_allocate_exception",
                          "__cxa_begin_catch",
                          "__gxx_personality_v0",
                          "_Unwind_Resume",
                          "_Unwind_RaiseException",
                          "__aeabi_unwind_cpp_pr0",
                          "__aeabi_unwind_cpp_pr1",
                          "__cxa_atexit",
                          "__cxa_guard_acquire",
                          "_ZTVN10__cxxabiv117__class_type_infoE"}) {
    EXPECT_EQ(syms.count(bad), 0u) << "the firmware image links " << bad;
  }
}

// The vector table sits at the start of flash: initial stack pointer in RAM, reset vector on
// Reset_Handler (Thumb bit set), and the ELF entry point is the same handler.
TEST(FirmwareArmTest, VectorTableAtFlashStart) {
  if (kElf.empty()) GTEST_SKIP() << "ARM build disabled (OMNI_BUILD_FIRMWARE_ARM=OFF)";
  const std::string cmd = "arm-none-eabi-objdump -s -j .isr_vector '" + kElf +
                          "' 2>&1 | grep -m1 '^ 8000000'; arm-none-eabi-nm '" + kElf +
                          "' | grep ' Reset_Handler$'";
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  char a[512] = {0}, b[512] = {0};
  ASSERT_NE(std::fgets(a, sizeof(a), p), nullptr) << "no .isr_vector at 0x08000000";
  ASSERT_NE(std::fgets(b, sizeof(b), p), nullptr) << "no Reset_Handler";
  pclose(p);
  // objdump line: " 8000000 SSSSSSSS RRRRRRRR ..." (little-endian words).
  std::istringstream line(a);
  std::string addr, sp_le, reset_le;
  line >> addr >> sp_le >> reset_le;
  auto le = [](const std::string& h) {
    unsigned long v = 0;
    for (int i = 3; i >= 0; --i) v = (v << 8) | std::stoul(h.substr(2 * i, 2), nullptr, 16);
    return v;
  };
  const unsigned long sp = le(sp_le), reset = le(reset_le);
  const unsigned long handler = std::stoul(std::string(b).substr(0, 8), nullptr, 16);
  EXPECT_GE(sp, 0x20000000ul);
  EXPECT_LE(sp, 0x20000000ul + 128 * 1024);
  EXPECT_EQ(reset, handler | 1ul) << "reset vector must point at Reset_Handler (Thumb)";
}

TEST(FirmwareArmTest, WithinFlashAndRamBudget) {
  if (kElf.empty()) GTEST_SKIP() << "ARM build disabled (OMNI_BUILD_FIRMWARE_ARM=OFF)";
  const std::string size_file = kElf.substr(0, kElf.rfind('/')) + "/size.txt";
  std::ifstream in(size_file);
  ASSERT_TRUE(in.good()) << size_file << " missing (written by the ARM build)";
  long flash = -1, ram = -1;
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("flash_bytes=", 0) == 0) flash = std::stol(line.substr(12));
    if (line.rfind("ram_bytes=", 0) == 0) ram = std::stol(line.substr(10));
  }
  ASSERT_GT(flash, 0);
  ASSERT_GT(ram, 0);
  EXPECT_LE(flash, 32 * 1024) << "flash budget";
  EXPECT_LE(ram, 8 * 1024) << "RAM budget (data + bss + 2 KiB stack)";
  std::printf("STM32F405 image: flash %ld bytes, RAM %ld bytes (incl. stack)\n", flash, ram);
}

}  // namespace
