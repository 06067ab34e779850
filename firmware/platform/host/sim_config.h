// Options of the firmware simulator process, read from one YAML file (config/firmware_sim.yaml).
#pragma once

#include <string>

#include "omni/common/result.h"
#include "omni/firmware/params.h"
#include "plant.h"

namespace omni::firmware::sim {

struct SimOptions {
  std::string can_url = "shm:omni0";  // the bus the simulated board is wired to
  Params firmware;                    // firmware parameters at boot
  PlantParams plant;
};

// Reads `path`; every missing, misspelled or out-of-range key is an error naming it.
Result<SimOptions> LoadSimOptions(const std::string& path);
Result<SimOptions> LoadSimOptionsFromString(const std::string& yaml, const std::string& name);

}  // namespace omni::firmware::sim
