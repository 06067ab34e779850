// g2o / TORO pose graphs (`omni posegraph`, `posegraph-check`): any text into the parser. A
// graph it accepts must have finite poses and measurements, and every edge must join two
// vertices it holds. Seeds: the first lines of the 2D and 3D graphs in ../shared/datasets.
#include <cmath>
#include <set>
#include <sstream>

#include "fuzz.h"
#include "omni/io/g2o.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size));
  auto graph = omni::io::ParsePoseGraph(in, "fuzz");
  if (!graph.ok()) {
    OMNI_FUZZ_CHECK(!graph.status().message().empty());
    return 0;
  }
  const omni::io::PoseGraph& g = graph.value();
  std::set<int> ids2, ids3;
  for (const auto& v : g.vertices2) ids2.insert(v.id);
  for (const auto& v : g.vertices3) ids3.insert(v.id);
  for (const auto& v : g.vertices2)
    OMNI_FUZZ_CHECK(std::isfinite(v.pose.x) && std::isfinite(v.pose.y) &&
                    std::isfinite(v.pose.theta));
  for (const auto& v : g.vertices3) OMNI_FUZZ_CHECK(v.pose.matrix().allFinite());
  for (const auto& e : g.edges2) {
    OMNI_FUZZ_CHECK(ids2.count(e.from) && ids2.count(e.to));
    OMNI_FUZZ_CHECK(e.information.allFinite());
    OMNI_FUZZ_CHECK(std::isfinite(e.measurement.x) && std::isfinite(e.measurement.y) &&
                    std::isfinite(e.measurement.theta));
  }
  for (const auto& e : g.edges3) {
    OMNI_FUZZ_CHECK(ids3.count(e.from) && ids3.count(e.to));
    OMNI_FUZZ_CHECK(e.information.allFinite() && e.measurement.matrix().allFinite());
  }
  return 0;
}

// The vertices below id 25 of a real graph and the edges among them: a small graph the parser
// accepts, in the file's own bytes (a plain prefix would end in edges to vertices cut off).
void omni::fuzz::Seeds(SeedList* seeds) {
  for (const char* file : {"pose-graphs/intel.g2o", "pose-graphs/M3500.g2o",
                           "pose-graphs/sphere2500.g2o", "pose-graphs/parking-garage.g2o"}) {
    SeedList whole;
    if (!whole.AddDatasetLines(file, 8 << 20)) {
      seeds->missing.insert(seeds->missing.end(), whole.missing.begin(), whole.missing.end());
      continue;
    }
    std::istringstream lines(whole.inputs[0]);
    std::string line, kept;
    while (std::getline(lines, line)) {
      std::istringstream fields(line);
      std::string tag;
      int a = 0, b = 0;
      fields >> tag >> a;
      const bool edge = tag.rfind("EDGE", 0) == 0;
      if (edge) fields >> b;
      if (!fields || a >= 25 || (edge && b >= 25)) continue;
      kept += line + "\n";
    }
    seeds->Add(kept);
  }
}
