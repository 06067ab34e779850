// JsonEscape: what goes between JSON quotes in the reports the tools write.
#include "omni/common/json.h"

#include <string>

#include <gtest/gtest.h>

namespace omni {
namespace {

TEST(JsonEscape, QuotesBackslashesAndControlBytesAreEscapedTheRestKept) {
  EXPECT_EQ(JsonEscape(""), "");
  EXPECT_EQ(JsonEscape("maps/pg/map.yaml"), "maps/pg/map.yaml");
  EXPECT_EQ(JsonEscape("a \"b\" c"), "a \\\"b\\\" c");
  EXPECT_EQ(JsonEscape("C:\\maps"), "C:\\\\maps");
  EXPECT_EQ(JsonEscape(std::string("tab\there\nnul") + '\0' + "x"),
            "tab\\u0009here\\u000anul\\u0000x");
  EXPECT_EQ(JsonEscape("\x1f\x7f"), "\\u001f\x7f");
  EXPECT_EQ(JsonEscape("Kraków ü"), "Kraków ü");  // UTF-8 passes through
}

}  // namespace
}  // namespace omni
