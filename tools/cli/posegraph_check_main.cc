// omni-posegraph-check: reads a g2o/TORO pose graph and prints its size; errors name the line.
#include <cstdio>
#include <cstring>

#include "omni/io/g2o.h"

int main(int argc, char** argv) {
  if (argc != 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h")) {
    std::fprintf(argc == 2 ? stdout : stderr,
                 "usage: omni posegraph-check GRAPH.g2o\n  Validates a g2o (SE2, SE3:QUAT) or TORO "
                 "graph.\n");
    return argc == 2 ? 0 : 2;
  }
  auto g = omni::io::ReadPoseGraph(argv[1]);
  if (!g.ok()) {
    std::fprintf(stderr, "omni posegraph-check: %s\n", g.error().message.c_str());
    return 1;
  }
  if (g->vertices2.empty() && g->vertices3.empty()) {
    std::fprintf(stderr, "omni posegraph-check: %s: no vertices (an empty or non-g2o file)\n",
                 argv[1]);
    return 1;
  }
  if (g->is_3d())
    std::printf("%s: 3D graph, %zu vertices, %zu edges\n", argv[1], g->vertices3.size(),
                g->edges3.size());
  else
    std::printf("%s: 2D graph, %zu vertices, %zu edges\n", argv[1], g->vertices2.size(),
                g->edges2.size());
  return 0;
}
