#include "omni/common/config.h"

#include <fstream>

#include <gtest/gtest.h>

#include "test_paths.h"

namespace omni {
namespace {

struct Options {
  int particles = 30;
  double sigma = 0.1;
  std::string mode = "fast";
  bool enabled = false;
  double alpha = 0.0;
};

Status Load(const std::string& yaml, Options* o) {
  auto r = ConfigReader::FromString(yaml, "mapper.yaml");
  if (!r.ok()) return r.error();
  r->Get("particles", &o->particles, Required(), InRange(1, 1000));
  r->Get("sigma", &o->sigma, Optional(), Positive<double>());
  r->Get("mode", &o->mode, Optional(), OneOf({"fast", "exact"}));
  r->Get("enabled", &o->enabled, Optional());
  auto motion = r->Section("motion");
  motion.Get("alpha", &o->alpha, Optional(), NonNegative<double>());
  return r->Finish();
}

TEST(Config, ValidFileFillsOptions) {
  Options o;
  ASSERT_TRUE(
      Load("particles: 50\nsigma: 0.2\nmode: exact\nenabled: true\nmotion:\n  alpha: 0.3\n", &o)
          .ok());
  EXPECT_EQ(o.particles, 50);
  EXPECT_DOUBLE_EQ(o.sigma, 0.2);
  EXPECT_EQ(o.mode, "exact");
  EXPECT_TRUE(o.enabled);
  EXPECT_DOUBLE_EQ(o.alpha, 0.3);
}

TEST(Config, MissingRequiredKeyIsNamed) {
  Options o;
  const Status s = Load("sigma: 0.2\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("mapper.yaml"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("'particles'"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("required key is missing"), std::string::npos) << s.message();
}

TEST(Config, MisspelledKeyIsNamedWithLine) {
  Options o;
  const Status s = Load("particles: 5\nsigmaa: 0.2\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("mapper.yaml:2"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("'sigmaa'"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("not a known option"), std::string::npos) << s.message();
}

// Found by the configuration review of 2026-12-06: a key given twice (the first one used to win
// silently) and a key left without a value (the default used to be taken silently).
TEST(Config, DuplicateAndEmptyKeysAreErrors) {
  Options o;
  Status s = Load("particles: 5\nsigma: 0.2\nparticles: 7\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("mapper.yaml:3: key 'particles' is given twice (also on line 1)"),
            std::string::npos)
      << s.message();
  s = Load("particles: 5\nsigma:\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("'sigma'"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("has no value"), std::string::npos) << s.message();
}

TEST(Config, MisspelledNestedKeyIsNamed) {
  Options o;
  const Status s = Load("particles: 5\nmotion:\n  alpah: 1\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("'motion.alpah'"), std::string::npos) << s.message();
}

TEST(Config, WrongTypeIsNamed) {
  Options o;
  const Status s = Load("particles: many\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("'particles' = 'many'"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("wrong type"), std::string::npos) << s.message();
}

TEST(Config, OutOfRangeNamesTheRule) {
  Options o;
  const Status s = Load("particles: 0\nsigma: -1\nmode: slow\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("'particles' = '0': must be in [1, 1000]"), std::string::npos)
      << s.message();
  EXPECT_NE(s.message().find("'sigma' = '-1': must be > 0"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("must be one of: fast exact"), std::string::npos) << s.message();
  EXPECT_EQ(o.particles, 30) << "a rejected value must not be stored";
}

TEST(Config, NonFiniteNumberRejected) {
  Options o;
  const Status s = Load("particles: 3\nsigma: .nan\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("finite"), std::string::npos) << s.message();
}

TEST(Config, MissingFileAndBadYaml) {
  auto r = ConfigReader::FromFile("/nonexistent/omni.yaml");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("/nonexistent/omni.yaml"), std::string::npos);
  auto bad = ConfigReader::FromString("a: [1, 2\nb: 3\n", "broken.yaml");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("broken.yaml:"), std::string::npos) << bad.error().message;
}

// YAML lets a key be a list or a map ("? [a, b]\n: 1", "{[1]: 2}"). No option is named that way:
// it is an error naming the line, like any unknown key, never an exception out of Finish() or
// Keys().
TEST(Config, AKeyThatIsNotANameIsAnError) {
  Options o;
  for (const char* yaml : {"particles: 3\n? [a, b]\n: 1\n", "particles: 3\n{x: 1}: 2\n",
                           "particles: 3\nmotion:\n  ? [alpha]\n  : 1\n"}) {
    Status s = Status::Ok();
    EXPECT_NO_THROW(s = Load(yaml, &o)) << yaml;
    ASSERT_FALSE(s.ok()) << yaml;
    EXPECT_NE(s.message().find("mapper.yaml:"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find("not a name"), std::string::npos) << s.message();
  }
  auto r = ConfigReader::FromString("one: 1\n[two]: 2\nthree: 3\n", "procs.yaml");
  ASSERT_TRUE(r.ok());
  std::vector<std::string> keys;
  EXPECT_NO_THROW(keys = r->Keys());
  EXPECT_EQ(keys, (std::vector<std::string>{"one", "three"}));
}

// A wrong value is quoted in the error, but not without end: a long list, a pasted blob or an
// alias of a large section is cut to its first 80 bytes, on a UTF-8 character boundary.
TEST(Config, ALongWrongValueIsQuotedShort) {
  Options o;
  std::string list = "particles: [";
  for (int i = 0; i < 2000; ++i) list += std::to_string(i) + ", ";
  list += "1]\n";
  Status s = Load(list, &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("'particles' = '[0, 1, 2, "), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("... ("), std::string::npos) << s.message();
  EXPECT_LT(s.message().size(), 300u) << s.message();

  std::string blob = "mode: ";
  for (int i = 0; i < 100; ++i) blob += "\xc3\xa9";  // 'e' with an acute accent, 2 bytes each
  s = Load(blob + "\n", &o);
  ASSERT_FALSE(s.ok());
  const std::string m = s.message();
  const size_t at = m.find("'mode' = '") + 10, end = m.find("... (200 bytes)");
  ASSERT_NE(end, std::string::npos) << m;
  EXPECT_EQ((end - at) % 2, 0u) << "cut inside a character: " << m;
  EXPECT_LE(end - at, 80u);

  // A value of nested aliases quotes short as well (yaml-cpp emits them with anchors).
  std::string laughs = "l0: &l0 {a: 1, b: 2}\n";
  for (int i = 1; i < 30; ++i)
    laughs += "l" + std::to_string(i) + ": &l" + std::to_string(i) + " {p: *l" +
              std::to_string(i - 1) + ", q: *l" + std::to_string(i - 1) + "}\n";
  s = Load(laughs + "particles: *l29\n", &o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("'particles' = '{p: "), std::string::npos) << s.message();
}

}  // namespace
}  // namespace omni
