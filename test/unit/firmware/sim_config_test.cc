#include <gtest/gtest.h>

#include "sim_config.h"

namespace omni::firmware::sim {
namespace {

TEST(SimConfigTest, ShippedConfigLoads) {
  auto o = LoadSimOptions(std::string(OMNI_SOURCE_DIR) + "/config/firmware_sim.yaml");
  ASSERT_TRUE(o.ok()) << o.error().ToString();
  EXPECT_EQ(o->firmware.watchdog_ms, 200u);
  EXPECT_EQ(o->plant.slip[0], 0.0);
}

TEST(SimConfigTest, BadValuesNamed) {
  auto o = LoadSimOptionsFromString("can: shm:x\nplant: {slip: [0.1, 2.0, 0], gear_ratoi: 3}\n",
                                    "inline");
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("plant.slip"), std::string::npos) << o.error().message;
  EXPECT_NE(o.error().message.find("gear_ratoi"), std::string::npos) << o.error().message;
}

}  // namespace
}  // namespace omni::firmware::sim
