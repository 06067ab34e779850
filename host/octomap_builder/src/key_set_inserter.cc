#include "omni/octomap_builder/key_set_inserter.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>

#include <sys/mman.h>

namespace omni::octo {
namespace {

constexpr uint64_t kEmpty = ~uint64_t{0};  // never a packed key (those use 48 bits)

inline uint64_t Mix(uint64_t k) {
  k ^= k >> 31;
  k *= 0x9E3779B97F4A7C15ull;
  k ^= k >> 29;
  return k;
}

// Open-addressing (linear probing) set of packed keys; grows at half load.
class KeyHashSet {
 public:
  explicit KeyHashSet(size_t expected = 1024) { Rehash(Capacity(expected)); }

  bool Insert(uint64_t key) {
    size_t i = Mix(key) >> shift_;
    for (;;) {
      const uint64_t s = slots_[i];
      if (s == key) return false;
      if (s == kEmpty) break;
      i = (i + 1) & mask_;
    }
    slots_[i] = key;
    if (++size_ * 2 > slots_.size()) Rehash(slots_.size() * 2);
    return true;
  }
  bool Contains(uint64_t key) const {
    size_t i = Mix(key) >> shift_;
    for (;;) {
      const uint64_t s = slots_[i];
      if (s == key) return true;
      if (s == kEmpty) return false;
      i = (i + 1) & mask_;
    }
  }
  template <class F>
  void ForEach(F&& f) const {
    for (uint64_t s : slots_)
      if (s != kEmpty) f(s);
  }
  size_t size() const { return size_; }

 private:
  static size_t Capacity(size_t expected) {
    size_t c = 64;
    while (c < expected * 2) c *= 2;
    return c;
  }
  void Rehash(size_t capacity) {
    std::vector<uint64_t> old;
    old.swap(slots_);
    slots_.assign(capacity, kEmpty);
    mask_ = capacity - 1;
    int bits = 0;
    while ((size_t{1} << bits) < capacity) ++bits;
    shift_ = 64 - bits;
    size_ = 0;
    for (uint64_t s : old)
      if (s != kEmpty) Insert(s);
  }

  std::vector<uint64_t> slots_;
  size_t mask_ = 0;
  int shift_ = 64;
  size_t size_ = 0;
};

inline uint64_t PackKey(const octomap::OcTreeKey& k) {
  return static_cast<uint64_t>(k[0]) | (static_cast<uint64_t>(k[1]) << 16) |
         (static_cast<uint64_t>(k[2]) << 32);
}

inline size_t ShardOf(uint64_t key, size_t shards) {
  // Low bits of a different mix than the table index (which uses the high bits).
  return static_cast<size_t>((key * 0xC2B2AE3D27D4EB4Full) >> 40) % shards;
}

// Interleaves the 16 bits of v into bits 0, 3, 6, ... and back.
inline uint64_t Spread16(uint64_t v) {
  v &= 0xffff;
  v = (v | (v << 16)) & 0x0000FF0000FFull;
  v = (v | (v << 8)) & 0x00F00F00F00Full;
  v = (v | (v << 4)) & 0x0C30C30C30C3ull;
  v = (v | (v << 2)) & 0x249249249249ull;
  return v;
}
inline uint64_t Compact16(uint64_t v) {
  v &= 0x249249249249ull;
  v = (v | (v >> 2)) & 0x0C30C30C30C3ull;
  v = (v | (v >> 4)) & 0x00F00F00F00Full;
  v = (v | (v >> 8)) & 0x0000FF0000FFull;
  v = (v | (v >> 16)) & 0xffff;
  return v;
}
inline uint64_t MortonOfPacked(uint64_t packed) {
  return Spread16(packed) | (Spread16(packed >> 16) << 1) | (Spread16(packed >> 32) << 2);
}

// LSD radix sort of values below 2^49 (11-bit digits); `tmp` is scratch of the same size.
void RadixSort49(std::vector<uint64_t>* v, std::vector<uint64_t>* tmp) {
  if (v->size() < 2048) {
    std::sort(v->begin(), v->end());
    return;
  }
  tmp->resize(v->size());
  constexpr int kBits = 11;
  constexpr size_t kBuckets = size_t{1} << kBits;
  std::vector<size_t> count(kBuckets);
  for (int pass = 0; pass * kBits < 49; ++pass) {
    const int shift = pass * kBits;
    std::fill(count.begin(), count.end(), 0);
    for (uint64_t x : *v) ++count[(x >> shift) & (kBuckets - 1)];
    size_t sum = 0;
    for (auto& c : count) {
      const size_t n = c;
      c = sum;
      sum += n;
    }
    for (uint64_t x : *v) (*tmp)[count[(x >> shift) & (kBuckets - 1)]++] = x;
    v->swap(*tmp);
  }
}

// OcTreeBaseImpl::computeRayKeys (octomap 1.9.7) with the keys handed to `emit` (packed)
// instead of a KeyRay: the same arithmetic in the same order (float point, double DDA state),
// so the same keys and the same tie-breaking. Faster by being inlined, by stepping a packed
// key (one add, one compare) and by choosing the axis without branches.
template <class Emit>
inline bool CastRay(const octomap::OcTree& keyer, const octomap::point3d& origin,
                    const octomap::point3d& end, Emit&& emit) {
  octomap::OcTreeKey key_origin, key_end;
  if (!keyer.coordToKeyChecked(origin, key_origin) || !keyer.coordToKeyChecked(end, key_end))
    return false;
  if (key_origin == key_end) return true;
  emit(PackKey(key_origin));
  octomap::point3d direction = (end - origin);
  const float length = static_cast<float>(direction.norm());
  direction /= length;
  const double resolution = keyer.getResolution();
  double t_max[3];
  double t_delta[3];
  uint64_t step[3];  // added to the packed key: +-1 in the field of the axis
  for (unsigned i = 0; i < 3; ++i) {
    int s = 0;
    if (direction(i) > 0.0)
      s = 1;
    else if (direction(i) < 0.0)
      s = -1;
    step[i] = static_cast<uint64_t>(static_cast<int64_t>(s) * (int64_t{1} << (16 * i)));
    if (s != 0) {
      double voxel_border = keyer.keyToCoord(key_origin[i]);
      voxel_border += static_cast<float>(s * resolution * 0.5);
      t_max[i] = (voxel_border - origin(i)) / direction(i);
      t_delta[i] = resolution / std::fabs(direction(i));
    } else {
      t_max[i] = std::numeric_limits<double>::max();
      t_delta[i] = std::numeric_limits<double>::max();
    }
  }
  uint64_t current = PackKey(key_origin);
  const uint64_t last = PackKey(key_end);
  const double len = length;
  // The state lives in registers; the axis is chosen arithmetically (upstream's nested
  // if/else: x if tx < ty and tx < tz; else y if ty < tz (and not tx < ty); else z).
  double tx = t_max[0], ty = t_max[1], tz = t_max[2];
  const double dx = t_delta[0], dy = t_delta[1], dz = t_delta[2];
  for (;;) {
    const unsigned a = tx < ty, b = tx < tz, c = ty < tz;
    const unsigned is_x = a & b, is_y = (a ^ 1u) & c, is_z = 1u - is_x - is_y;
    current += step[2 - 2 * is_x - is_y];
    tx += is_x ? dx : 0.0;
    ty += is_y ? dy : 0.0;
    tz += is_z ? dz : 0.0;
    if (current == last) break;
    if (std::min(std::min(tx, ty), tz) > len) break;
    emit(current);
  }
  return true;
}

// Casts the rays of `points` taken in chunks from `*next` (shared by the threads, so long and
// short rays balance out): the free keys of each ray go to `free(packed)`, the end point's key,
// for a point within `maxrange`, to `occupied(packed)`. Same expressions as
// OccupancyOcTreeBase::computeUpdate, so the same keys.
template <class Free, class Occupied>
void CastRays(const octomap::OcTree& keyer, const std::vector<Eigen::Vector3f>& points,
              const octomap::point3d& origin, double maxrange, std::atomic<size_t>* next,
              Free&& free, Occupied&& occupied) {
  constexpr size_t kChunk = 512;
  for (;;) {
    const size_t begin = next->fetch_add(kChunk);
    if (begin >= points.size()) break;
    const size_t end = std::min(points.size(), begin + kChunk);
    for (size_t i = begin; i < end; ++i) {
      const octomap::point3d p(points[i].x(), points[i].y(), points[i].z());
      if ((maxrange < 0.0) || ((p - origin).norm() <= maxrange)) {
        CastRay(keyer, origin, p, free);
        octomap::OcTreeKey key;
        if (keyer.coordToKeyChecked(p, key)) occupied(PackKey(key));
      } else {
        const octomap::point3d direction = (p - origin).normalized();
        CastRay(keyer, origin, origin + direction * static_cast<float>(maxrange), free);
      }
    }
  }
}

template <class F>
void RunOnThreads(int n, F&& f) {
  std::vector<std::thread> threads;
  threads.reserve(static_cast<size_t>(n > 0 ? n - 1 : 0));
  for (int t = 1; t < n; ++t) threads.emplace_back([&f, t] { f(t); });
  f(0);
  for (auto& th : threads) th.join();
}

// Zero-filled anonymous memory reserved without being committed: pages become resident when
// first written, so a large bounding box costs only what the rays touch. Unmapped on scope exit.
class ReservedZeroMemory {
 public:
  explicit ReservedZeroMemory(size_t bytes) : bytes_(bytes) {
    void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE,
                     MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    data_ = p == MAP_FAILED ? nullptr : p;
  }
  ~ReservedZeroMemory() {
    if (data_ != nullptr) ::munmap(data_, bytes_);
  }
  ReservedZeroMemory(const ReservedZeroMemory&) = delete;
  ReservedZeroMemory& operator=(const ReservedZeroMemory&) = delete;
  void* data() const { return data_; }

 private:
  size_t bytes_;
  void* data_ = nullptr;
};

// Position of a voxel inside its 8×8×8 brick: the Morton code of its low three key bits per
// axis (x in bits 0, 3, 6; y in 1, 4, 7; z in 2, 5, 8), so the brick's 512 bits are in the
// octree's child order.
constexpr uint32_t Spread3(uint32_t v) { return (v & 1u) | ((v & 2u) << 2) | ((v & 4u) << 4); }

// One 8×8×8 brick per 128 bytes: 8 words of free bits, then 8 words of occupied bits.
constexpr size_t kBrickWords = 16;
constexpr size_t kOccupiedWords = 8;

// The bitmap over a box of keys whose low corner is a multiple of 8 on every axis, so bricks
// are aligned with the octree's nodes at depth 13 and Morton(brick position) << 9 | position in
// the brick is the key's Morton code.
struct BrickBox {
  uint32_t lo[3] = {0, 0, 0};  // lowest key of the box (multiples of 8)
  uint32_t bricks[3] = {0, 0, 0};
  uint64_t* bits = nullptr;    // kBrickWords words per brick
  uint8_t* touched = nullptr;  // one flag per brick: some bit of it was set

  size_t Count() const { return size_t{bricks[0]} * bricks[1] * bricks[2]; }
  uint64_t BrickMorton(size_t b) const {
    const uint64_t bx = lo[0] / 8 + b % bricks[0];
    const uint64_t by = lo[1] / 8 + (b / bricks[0]) % bricks[1];
    const uint64_t bz = lo[2] / 8 + b / (size_t{bricks[0]} * bricks[1]);
    return MortonOfPacked(bx | (by << 16) | (bz << 32));
  }
  size_t BrickOfMorton(uint64_t code) const {
    const size_t bx = Compact16(code) - lo[0] / 8, by = Compact16(code >> 1) - lo[1] / 8,
                 bz = Compact16(code >> 2) - lo[2] / 8;
    return (bz * bricks[1] + by) * bricks[0] + bx;
  }
};

// Marks keys of one scan in a BrickBox; one per thread. `kShared`: other threads write the same
// box at the same time (bits are set with atomic OR; a bit already set costs one plain load).
// A key's bit address is the sum of one table entry per axis (the brick's offset along that axis
// plus the axis' bits of the Morton position in the brick), so a ray step costs three loads
// from small, cache-resident tables.
template <bool kShared>
class BrickMarker {
 public:
  explicit BrickMarker(const BrickBox& box) : bits_(box.bits), touched_(box.touched) {
    const uint64_t brick_bits = kBrickWords * 64;
    const uint64_t stride[3] = {brick_bits, brick_bits * box.bricks[0],
                                brick_bits * box.bricks[0] * box.bricks[1]};
    for (unsigned i = 0; i < 3; ++i) {
      lo_[i] = box.lo[i];
      extent_[i] = box.bricks[i] * 8;
      table_[i].resize(extent_[i]);
      for (uint32_t r = 0; r < extent_[i]; ++r)
        table_[i][r] = (r >> 3) * stride[i] + (uint64_t{Spread3(r & 7)} << i);
    }
    tx_ = table_[0].data();
    ty_ = table_[1].data();
    tz_ = table_[2].data();
  }
  // `bit0`: 0 for the free bits, kOccupiedWords * 64 for the occupied ones.
  inline __attribute__((always_inline)) void Mark(uint64_t packed, uint64_t bit0) {
    const uint32_t rx = static_cast<uint32_t>(packed & 0xffff) - lo_[0];
    const uint32_t ry = static_cast<uint32_t>((packed >> 16) & 0xffff) - lo_[1];
    const uint32_t rz = static_cast<uint32_t>(packed >> 32) - lo_[2];
    if (__builtin_expect(rx >= extent_[0] || ry >= extent_[1] || rz >= extent_[2], 0)) {
      Outside(packed);
      return;
    }
    const uint64_t a = tx_[rx] + ty_[ry] + tz_[rz] + bit0;
    uint64_t* w = bits_ + (a >> 6);
    const uint64_t bit = uint64_t{1} << (a & 63);
    const size_t b = a / (kBrickWords * 64);
    if constexpr (kShared) {
      if (__atomic_load_n(w, __ATOMIC_RELAXED) & bit) return;
      __atomic_fetch_or(w, bit, __ATOMIC_RELAXED);
      if (__atomic_load_n(&touched_[b], __ATOMIC_RELAXED) == 0 &&
          __atomic_exchange_n(&touched_[b], uint8_t{1}, __ATOMIC_RELAXED) == 0)
        touched.push_back(static_cast<uint32_t>(b));
    } else {
      if (*w & bit) return;
      *w |= bit;
      if (touched_[b] == 0) {
        touched_[b] = 1;
        touched.push_back(static_cast<uint32_t>(b));
      }
    }
  }

  std::vector<uint32_t> touched;  // bricks this marker was first to write
  std::vector<uint64_t> outside;  // packed keys outside the box (free keys only)

 private:
  // A ray step outside the box of its end points (only a rounding corner case of the DDA could
  // do this; the box has a one-voxel margin): kept aside, never lost.
  __attribute__((noinline)) void Outside(uint64_t packed) { outside.push_back(packed); }

  uint64_t* bits_;
  uint8_t* touched_;
  uint32_t lo_[3];
  uint32_t extent_[3];
  std::vector<uint64_t> table_[3];
  const uint64_t* tx_;
  const uint64_t* ty_;
  const uint64_t* tz_;
};

}  // namespace

uint64_t MortonCode(const octomap::OcTreeKey& key) { return MortonOfPacked(PackKey(key)); }

octomap::OcTreeKey KeyFromMorton(uint64_t code) {
  return octomap::OcTreeKey(static_cast<uint16_t>(Compact16(code)),
                            static_cast<uint16_t>(Compact16(code >> 1)),
                            static_cast<uint16_t>(Compact16(code >> 2)));
}

std::vector<octomap::OcTreeKey> KeySets::Free() const {
  std::vector<octomap::OcTreeKey> keys;
  for (uint64_t u : updates)
    if (!(u & 1)) keys.push_back(KeyFromMorton(u >> 1));
  return keys;
}

std::vector<octomap::OcTreeKey> KeySets::Occupied() const {
  std::vector<octomap::OcTreeKey> keys;
  for (uint64_t u : updates)
    if (u & 1) keys.push_back(KeyFromMorton(u >> 1));
  return keys;
}

ParallelKeySetInserter::ParallelKeySetInserter(double resolution_m, const KeySetOptions& options)
    : options_(options), keyer_(resolution_m) {
  if (options_.num_threads < 1) options_.num_threads = 1;
}

int64_t ParallelKeySetInserter::NowMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

namespace {
// Per-frame working memory, kept between frames by the thread that inserts them. Allocated anew
// for every frame, the tables and the reduced cloud (about 2 MB for a 320x240 depth frame) are
// mapped blocks: fresh zeroed pages each time (see omni/common/malloc_setup.h), a page fault per
// 4 KiB touched.
struct SubvoxelAcc {
  double x = 0, y = 0, z = 0;
  int n = 0;
};
struct FrameScratch {
  std::vector<uint64_t> slot_key;
  std::vector<uint32_t> slot_val;
  std::vector<SubvoxelAcc> acc;
  std::vector<Eigen::Vector3f> reduced;
  std::vector<uint64_t> order, sort_tmp;
};
FrameScratch& ThreadScratch() {
  static thread_local FrameScratch scratch;
  return scratch;
}
}  // namespace

void ParallelKeySetInserter::Discretize(const std::vector<Eigen::Vector3f>& points,
                                        std::vector<Eigen::Vector3f>* out) const {
  KeyHashSet seen(points.size() / 8 + 64);
  out->clear();
  out->reserve(points.size() / 4 + 16);
  for (const auto& p : points) {
    octomap::OcTreeKey k;
    if (!keyer_.coordToKeyChecked(octomap::point3d(p.x(), p.y(), p.z()), k)) continue;
    if (!seen.Insert(PackKey(k))) continue;
    const octomap::point3d c = keyer_.keyToCoord(k);
    out->emplace_back(c.x(), c.y(), c.z());
  }
}

void ParallelKeySetInserter::SubvoxelCentroids(const std::vector<Eigen::Vector3f>& points,
                                               std::vector<Eigen::Vector3f>* out) const {
  // Cell index per axis: floor(coord * n / resolution), offset into 20 bits (+-2^19 cells).
  const double scale = options_.subvoxel / keyer_.getResolution();
  constexpr int64_t kOffset = int64_t{1} << 19;
  FrameScratch& scratch = ThreadScratch();
  // Open-addressing map cell -> index of its accumulator (first-appearance order).
  std::vector<SubvoxelAcc>& acc = scratch.acc;
  acc.clear();
  acc.reserve(points.size() / 4 + 64);
  size_t cap = 64;
  while (cap < points.size() / 2) cap *= 2;
  std::vector<uint64_t>& slot_key = scratch.slot_key;
  std::vector<uint32_t>& slot_val = scratch.slot_val;
  slot_key.assign(cap * 2, ~uint64_t{0});
  slot_val.assign(cap * 2, 0);
  size_t mask = cap * 2 - 1;
  auto grow = [&]() {
    std::vector<uint64_t> nk(slot_key.size() * 2, ~uint64_t{0});
    std::vector<uint32_t> nv(nk.size(), 0);
    const size_t nm = nk.size() - 1;
    for (size_t i = 0; i < slot_key.size(); ++i) {
      if (slot_key[i] == ~uint64_t{0}) continue;
      size_t j = Mix(slot_key[i]) & nm;
      while (nk[j] != ~uint64_t{0}) j = (j + 1) & nm;
      nk[j] = slot_key[i];
      nv[j] = slot_val[i];
    }
    slot_key.swap(nk);
    slot_val.swap(nv);
    mask = nm;
  };
  for (const auto& p : points) {
    const int64_t ix = static_cast<int64_t>(std::floor(p.x() * scale)) + kOffset;
    const int64_t iy = static_cast<int64_t>(std::floor(p.y() * scale)) + kOffset;
    const int64_t iz = static_cast<int64_t>(std::floor(p.z() * scale)) + kOffset;
    if (ix < 0 || iy < 0 || iz < 0 || ix >= 2 * kOffset || iy >= 2 * kOffset || iz >= 2 * kOffset)
      continue;  // beyond +-2^19 cells: outside any tree of this resolution anyway
    const uint64_t k = static_cast<uint64_t>(ix) | (static_cast<uint64_t>(iy) << 20) |
                       (static_cast<uint64_t>(iz) << 40);
    size_t j = Mix(k) & mask;
    while (slot_key[j] != ~uint64_t{0} && slot_key[j] != k) j = (j + 1) & mask;
    if (slot_key[j] == ~uint64_t{0}) {
      slot_key[j] = k;
      slot_val[j] = static_cast<uint32_t>(acc.size());
      acc.emplace_back();
      if (acc.size() * 2 > slot_key.size()) grow();
      // Re-find after a possible growth.
      j = Mix(k) & mask;
      while (slot_key[j] != k) j = (j + 1) & mask;
    }
    SubvoxelAcc& a = acc[slot_val[j]];
    a.x += p.x();
    a.y += p.y();
    a.z += p.z();
    ++a.n;
  }
  out->clear();
  out->reserve(acc.size());
  for (const SubvoxelAcc& a : acc)
    out->emplace_back(static_cast<float>(a.x / a.n), static_cast<float>(a.y / a.n),
                      static_cast<float>(a.z / a.n));
}

KeySets ParallelKeySetInserter::ComputeKeySets(const std::vector<Eigen::Vector3f>& input,
                                               const Eigen::Vector3f& origin_in,
                                               InsertStats* stats) const {
  KeySets out;
  ComputeKeySets(input, origin_in, &out, stats);
  return out;
}

void ParallelKeySetInserter::ComputeKeySets(const std::vector<Eigen::Vector3f>& input,
                                            const Eigen::Vector3f& origin_in, KeySets* out,
                                            InsertStats* stats) const {
  const int64_t t0 = NowMicros();
  std::vector<Eigen::Vector3f>& reduced = ThreadScratch().reduced;
  const bool reduce = options_.discretize || options_.subvoxel > 1;
  if (options_.discretize)
    Discretize(input, &reduced);
  else if (options_.subvoxel > 1)
    SubvoxelCentroids(input, &reduced);
  const std::vector<Eigen::Vector3f>& points = reduce ? reduced : input;
  const int64_t t_reduced = NowMicros();

  // The bitmap path fills the kept storage in place; the hash-set fallback and the rare merge of
  // keys outside the box replace it.
  out->updates.clear();
  if (stats) {
    stats->points = input.size();
    stats->rays = points.size();
  }
  const bool done = options_.max_bitmap_bytes > 0 && BitmapKeySets(points, origin_in, out, stats);
  if (!done) HashKeySets(points, origin_in, out, stats);
  if (stats) {
    stats->rays_us += t_reduced - t0;  // the reduction is counted with the rays
    stats->keys_us = NowMicros() - t0;
  }
}

bool ParallelKeySetInserter::BitmapKeySets(const std::vector<Eigen::Vector3f>& points,
                                           const Eigen::Vector3f& origin_in, KeySets* result,
                                           InsertStats* stats) const {
  const int64_t t0 = NowMicros();
  const octomap::point3d origin(origin_in.x(), origin_in.y(), origin_in.z());
  const double maxrange = options_.max_range_m;
  octomap::OcTreeKey origin_key;
  if (!keyer_.coordToKeyChecked(origin, origin_key)) return false;  // no ray; rare: hash path

  // The box of the rays' end keys and the origin (same expressions as the casting below).
  uint32_t lo[3], hi[3];
  for (int i = 0; i < 3; ++i) lo[i] = hi[i] = origin_key[static_cast<unsigned>(i)];
  for (const auto& q : points) {
    const octomap::point3d p(q.x(), q.y(), q.z());
    octomap::OcTreeKey key;
    bool ok;
    if ((maxrange < 0.0) || ((p - origin).norm() <= maxrange)) {
      ok = keyer_.coordToKeyChecked(p, key);
    } else {
      const octomap::point3d direction = (p - origin).normalized();
      ok = keyer_.coordToKeyChecked(origin + direction * static_cast<float>(maxrange), key);
    }
    if (!ok) continue;
    for (unsigned i = 0; i < 3; ++i) {
      lo[i] = std::min<uint32_t>(lo[i], key[i]);
      hi[i] = std::max<uint32_t>(hi[i], key[i]);
    }
  }
  BrickBox box;
  for (int i = 0; i < 3; ++i) {
    box.lo[i] = (lo[i] > 0 ? lo[i] - 1 : 0) & ~7u;  // one voxel of margin, aligned down to 8
    const uint32_t top = std::min<uint32_t>(hi[i] + 1, 0xffff);
    box.bricks[i] = (top - box.lo[i]) / 8 + 1;
  }
  const size_t count = box.Count();
  if (count >= (size_t{1} << 32) || count > options_.max_bitmap_bytes / (kBrickWords * 8 + 1))
    return false;
  ReservedZeroMemory bits(count * kBrickWords * 8), touched(count);
  if (bits.data() == nullptr || touched.data() == nullptr) return false;
  box.bits = static_cast<uint64_t*>(bits.data());
  box.touched = static_cast<uint8_t*>(touched.data());

  // Phase 1: rays, in chunks handed out dynamically (ray lengths vary a lot).
  const int nt = options_.num_threads;
  std::vector<std::vector<uint32_t>> touched_lists(static_cast<size_t>(nt));
  std::vector<std::vector<uint64_t>> outside_lists(static_cast<size_t>(nt));
  std::atomic<size_t> next{0};
  auto cast_all = [&](auto& marker) {
    CastRays(
        keyer_, points, origin, maxrange, &next, [&marker](uint64_t k) { marker.Mark(k, 0); },
        [&marker](uint64_t k) { marker.Mark(k, kOccupiedWords * 64); });
  };
  RunOnThreads(nt, [&](int t) {
    const auto ti = static_cast<size_t>(t);
    if (nt == 1) {
      BrickMarker<false> marker(box);
      cast_all(marker);
      touched_lists[ti].swap(marker.touched);
      outside_lists[ti].swap(marker.outside);
    } else {
      BrickMarker<true> marker(box);
      cast_all(marker);
      touched_lists[ti].swap(marker.touched);
      outside_lists[ti].swap(marker.outside);
    }
  });
  const int64_t t_rays = NowMicros();

  // Phase 2: the touched bricks in Morton order of their position; in each, the bits in order.
  FrameScratch& scratch = ThreadScratch();
  std::vector<uint64_t>& order = scratch.order;
  order.clear();
  for (const auto& list : touched_lists)
    for (uint32_t b : list) order.push_back(box.BrickMorton(b));
  RadixSort49(&order, &scratch.sort_tmp);  // brick Morton codes have at most 39 bits
  // Thread t writes the updates of bricks [first[t], first[t+1]) at offset[t]: counted first.
  std::vector<size_t> first(static_cast<size_t>(nt) + 1), offset(static_cast<size_t>(nt) + 1, 0);
  std::vector<size_t> n_free(static_cast<size_t>(nt), 0), n_occ(static_cast<size_t>(nt), 0);
  for (int t = 0; t <= nt; ++t)
    first[static_cast<size_t>(t)] = order.size() * static_cast<size_t>(t) / static_cast<size_t>(nt);
  RunOnThreads(nt, [&](int t) {
    const auto ti = static_cast<size_t>(t);
    for (size_t k = first[ti]; k < first[ti + 1]; ++k) {
      const uint64_t* w = box.bits + box.BrickOfMorton(order[k]) * kBrickWords;
      for (size_t i = 0; i < 8; ++i) {
        const uint64_t occ = w[kOccupiedWords + i];
        n_occ[ti] += static_cast<size_t>(__builtin_popcountll(occ));
        n_free[ti] += static_cast<size_t>(__builtin_popcountll(w[i] & ~occ));
      }
    }
  });
  for (size_t t = 0; t < static_cast<size_t>(nt); ++t)
    offset[t + 1] = offset[t] + n_free[t] + n_occ[t];
  std::vector<uint64_t>& updates = result->updates;
  updates.resize(offset.back());
  RunOnThreads(nt, [&](int t) {
    const auto ti = static_cast<size_t>(t);
    uint64_t* out = updates.data() + offset[ti];
    for (size_t k = first[ti]; k < first[ti + 1]; ++k) {
      const uint64_t* w = box.bits + box.BrickOfMorton(order[k]) * kBrickWords;
      const uint64_t high = order[k] << 9;
      for (size_t i = 0; i < 8; ++i) {
        const uint64_t occ = w[kOccupiedWords + i];
        uint64_t any = occ | w[i];
        while (any != 0) {
          const unsigned bit = static_cast<unsigned>(__builtin_ctzll(any));
          *out++ = (high | (i << 6) | bit) << 1 | ((occ >> bit) & 1);
          any &= any - 1;
        }
      }
    }
  });
  const int64_t t_emit = NowMicros();

  // Free keys a ray stepped to outside the box (none in practice): sorted and merged in.
  std::vector<uint64_t> outside;
  for (const auto& list : outside_lists)
    for (uint64_t k : list) outside.push_back(MortonOfPacked(k) << 1);
  size_t n_outside = 0;
  if (!outside.empty()) {
    std::sort(outside.begin(), outside.end());
    outside.erase(std::unique(outside.begin(), outside.end()), outside.end());
    n_outside = outside.size();
    std::vector<uint64_t> merged(updates.size() + outside.size());
    std::merge(updates.begin(), updates.end(), outside.begin(), outside.end(), merged.begin());
    updates.swap(merged);
  }
  if (stats) {
    stats->bitmap = true;
    stats->free_keys = n_outside;
    stats->occupied_keys = 0;
    for (size_t t = 0; t < static_cast<size_t>(nt); ++t) {
      stats->free_keys += n_free[t];
      stats->occupied_keys += n_occ[t];
    }
    stats->rays_us = t_rays - t0;
    stats->merge_us = t_emit - t_rays;
    stats->sort_us = NowMicros() - t_emit;
  }
  return true;
}

void ParallelKeySetInserter::HashKeySets(const std::vector<Eigen::Vector3f>& points,
                                         const Eigen::Vector3f& origin_in, KeySets* result,
                                         InsertStats* stats) const {
  const int64_t t0 = NowMicros();
  const int nt = options_.num_threads;
  const octomap::point3d origin(origin_in.x(), origin_in.y(), origin_in.z());
  const double maxrange = options_.max_range_m;
  std::vector<KeyHashSet> free_local(static_cast<size_t>(nt), KeyHashSet(1 << 16));
  std::vector<KeyHashSet> occ_local(static_cast<size_t>(nt), KeyHashSet(points.size() / nt + 64));

  // Phase 1: rays, in chunks handed out dynamically (ray lengths vary a lot).
  std::atomic<size_t> next{0};
  RunOnThreads(nt, [&](int t) {
    KeyHashSet& fr = free_local[static_cast<size_t>(t)];
    KeyHashSet& oc = occ_local[static_cast<size_t>(t)];
    // Neighbouring rays (consecutive points of a depth image) cross mostly the same voxels: a
    // small direct-mapped filter of keys this thread already inserted, kept in cache, skips
    // most repeats before they reach the (large, cache-missing) hash set. Only keys already
    // in `fr` are in the filter, so nothing is lost.
    std::vector<uint64_t> recent(size_t{1} << 15, kEmpty);
    auto emit = [&fr, &recent](uint64_t packed) {
      uint64_t& slot = recent[Mix(packed) & ((size_t{1} << 15) - 1)];
      if (slot == packed) return;
      slot = packed;
      fr.Insert(packed);
    };
    CastRays(keyer_, points, origin, maxrange, &next, emit, [&oc](uint64_t k) { oc.Insert(k); });
  });

  const int64_t t_rays = NowMicros();
  // Phase 2: merge by shard; thread s owns the keys whose shard is s.
  // Each shard's output: Morton code << 1 | occupied, sorted.
  std::vector<std::vector<uint64_t>> shard_out(static_cast<size_t>(nt));
  std::vector<size_t> shard_free(static_cast<size_t>(nt), 0), shard_occ(static_cast<size_t>(nt), 0);
  RunOnThreads(nt, [&](int s) {
    const size_t shards = static_cast<size_t>(nt);
    const size_t me = static_cast<size_t>(s);
    size_t occ_guess = 0, free_guess = 0;
    for (int t = 0; t < nt; ++t) {
      occ_guess += occ_local[static_cast<size_t>(t)].size() / shards;
      free_guess += free_local[static_cast<size_t>(t)].size() / shards;
    }
    std::vector<uint64_t>& out = shard_out[me];
    out.reserve(occ_guess + free_guess);
    KeyHashSet occ(occ_guess + 64);
    for (const auto& set : occ_local)
      set.ForEach([&](uint64_t k) {
        if (ShardOf(k, shards) == me && occ.Insert(k)) out.push_back(MortonOfPacked(k) << 1 | 1);
      });
    KeyHashSet fr(free_guess + 64);
    for (const auto& set : free_local)
      set.ForEach([&](uint64_t k) {
        if (ShardOf(k, shards) == me && !occ.Contains(k) && fr.Insert(k))
          out.push_back(MortonOfPacked(k) << 1);
      });
    shard_occ[me] = occ.size();
    shard_free[me] = fr.size();
    std::vector<uint64_t> tmp;
    RadixSort49(&out, &tmp);
  });

  const int64_t t_merge = NowMicros();
  // Merge the sorted shards (pairwise; nt is small).
  KeySets& out = *result;
  out.updates = std::move(shard_out[0]);
  for (size_t i = 1; i < shard_out.size(); ++i) {
    std::vector<uint64_t> merged(out.updates.size() + shard_out[i].size());
    std::merge(out.updates.begin(), out.updates.end(), shard_out[i].begin(), shard_out[i].end(),
               merged.begin());
    out.updates.swap(merged);
  }
  size_t n_free = 0, n_occ = 0;
  for (size_t i = 0; i < shard_out.size(); ++i) {
    n_free += shard_free[i];
    n_occ += shard_occ[i];
  }
  if (stats) {
    stats->bitmap = false;
    stats->free_keys = n_free;
    stats->occupied_keys = n_occ;
    stats->rays_us = t_rays - t0;
    stats->merge_us = t_merge - t_rays;
    stats->sort_us = NowMicros() - t_merge;
  }
}

}  // namespace omni::octo
