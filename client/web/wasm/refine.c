// The split decoder of refine.js (stream version 6; docs/formats.md section 2) in C for
// WebAssembly: SplitState and ProgressiveLevels.decodeSplits step for step, the same
// integers out, in about half the time (docs/performance.md). Built by client/build_wasm.py
// (clang for wasm32 from the ziglang package) into client/web/js/refine.wasm; driven by
// client/web/js/wasm_splits.js. A stream's wedge keys (a mesh with appearance attributes)
// are decoded by refine.js's wedges.js, called from each split (wedge_split, below).
//
// Every index read from a frame is checked before it is used, as refine.js checks it (the
// caller, ProgressiveLevels.addFrame, has checked the frame's counts against the mesh):
// a hostile frame gets an error code, never a read or write outside the buffers.
#include <stdint.h>

typedef int32_t i32;
typedef uint32_t u32;
typedef int64_t i64;
typedef uint64_t u64;
typedef uint16_t u16;
typedef uint8_t u8;

// ---- memory: a bump allocator over the module's memory, grown on demand -------------
// Nothing is freed, and memory the module has not handed out is zero (WebAssembly's pages
// start so), so what take returns is zero without being cleared: a mesh's buffers (about
// 80 MB for dragon's) are written only where the decoder writes.
extern unsigned char __heap_base;
static u32 heap_top;
static void *take(u32 bytes) {
  if (!heap_top) heap_top = (u32)&__heap_base;
  heap_top = (heap_top + 15u) & ~15u;
  u32 at = heap_top;
  if (bytes > 0xffffffffu - at) return 0; // past 4 GiB: no room
  u32 end = at + bytes;
  u32 have = (u32)__builtin_wasm_memory_size(0) * 65536u;
  if (end > have) {
    u32 pages = (end - have + 65535u) / 65536u;
    if (__builtin_wasm_memory_grow(0, pages) == (unsigned long)-1) return 0;
  }
  heap_top = end;
  return (void *)at;
}

// ---- errors: a code wasm_splits.js turns into the message refine.js gives -----------
enum {
  OK = 0, E_SHORT, E_NOT_YET, E_WORK, E_COUNTS, E_NO_VERTEX, E_FACE_CODE, E_THIRD,
  E_RELABEL, E_GRID, E_TRAILING, E_MEMORY, E_BASE,
};
static i32 error;
static i64 error_split, error_value; // the split (its t) and the value a message names
#define FAIL(code) do { error = (code); return; } while (0)
#define FAIL_V(code, v) do { error = (code); return (v); } while (0)
i32 qem_error_split(void) { return (i32)error_split; }
i32 qem_error_value(void) { return (i32)error_value; }

// ---- the range decoder (range_coder.js) ----------------------------------------------
#define PROB_BITS 12
#define ONE (1 << PROB_BITS)
#define HALF (ONE >> 1)
#define RATE 4
#define TOP (1u << 24)
#define MAX_EXPONENT 32
#define PREFIX (MAX_EXPONENT + 1)
#define TOP_TREE 3
#define SIGN_SLOT (PREFIX + (MAX_EXPONENT + 1) * TOP_TREE)
#define IS (SIGN_SLOT + 1)
#define UNIFORM_SLOTS 64

static const u8 *data;
static u32 data_len, position;
static u32 range, code;
static i32 broken;
static u16 *probs;

static inline u32 next_byte(void) {
  u32 at = position++;
  if (at < data_len) return data[at];
  broken = 1;
  return 0;
}
static void coder_start(const u8 *bytes, u32 n) {
  data = bytes; data_len = n; position = 0; broken = 0; range = 0xffffffffu;
  u64 c = 0;
  for (int i = 0; i < 4; i++) c = c * 256 + next_byte();
  if (c >= 0xffffffffu) { broken = 1; c = 0; }
  code = (u32)c;
}
static inline void normalise(void) {
  while (range < TOP) { range <<= 8; code = (code << 8) | next_byte(); }
}
// A decision without a branch on its outcome (which is as unpredictable as the data):
// the masks select range_coder.js's two cases.
static inline i32 bit(i32 ctx) {
  u32 p = probs[ctx];
  u32 bound = (range >> PROB_BITS) * p;
  u32 one = (u32)0 - (u32)(code >= bound); // all ones for a 1
  code -= bound & one;
  range = (bound & ~one) | ((range - bound) & one);
  probs[ctx] = (u16)(p + ((((ONE - p) >> RATE) & ~one) - ((p >> RATE) & one)));
  normalise();
  return (i32)(one & 1u);
}
// A bit of even odds, again selected by a mask: its outcome is a coin toss, which a
// branch would mispredict half the time.
static inline i32 direct(void) {
  u32 r = range >> 1;
  range = r;
  u32 one = (u32)0 - (u32)(code >= r);
  code -= r & one;
  if (code >= r) { broken = 1; code = 0; }
  normalise();
  return (i32)(one & 1u);
}
static i32 tree(i32 base, i32 n_bits) {
  i32 node = 1;
  for (i32 j = 0; j < n_bits; j++) node = 2 * node + bit(base + node - 1);
  return node - (1 << n_bits);
}
static i64 integer(i32 base) {
  i32 exponent = 0;
  while (exponent < MAX_EXPONENT && bit(base + exponent)) exponent++;
  i32 rows = base + PREFIX + exponent * TOP_TREE;
  i64 n = 1;
  i32 node = 1;
  for (i32 j = 0; j < exponent; j++) {
    i32 b;
    if (j < 2) { b = bit(rows + node - 1); node = 2 * node + b; }
    else b = direct();
    n = 2 * n + b;
  }
  return n - 1;
}
static i64 uniform(i32 base, i64 n) {
  if (n <= 1) return 0;
  u32 top = (u32)(n - 1);
  i32 n_bits = 32 - __builtin_clz(top);
  i32 tight = 1;
  i64 value = 0;
  for (i32 j = n_bits - 1; j >= 0; j--) {
    if (tight && ((top >> j) & 1u) == 0) { value *= 2; continue; }
    i32 b = bit(base + j);
    value = 2 * value + b;
    if (b == 0) tight = 0;
  }
  return value;
}

// ---- the format's constants (refine.js) ------------------------------------------------
#define EXPLICIT_FACE 6
#define ESCAPE 255
#define SPAN_RING_LIMIT 64
#define FAN_SCAN 16
#define SMALL_SET 16
#define S_BUCKETS 32
#define S_BUCKET_BITS 5
#define DIFF_BITS 13
#define NORMAL_BITS 12
#define LAPLACE_BITS 20
#define FAN_BLOCK 16
#define FAN_Q 2 // where a block holds its vertex's grid position (3 int32s)
#define FAN_STAMP 5 // then the last set of neighbours the vertex was put in (refine.js's FAN_STAMP)
#define STAMP (FAN_STAMP - FAN_Q) // the stamp, from the position
#define FAN_CORNERS 6
#define FAN_INLINE (FAN_BLOCK - FAN_CORNERS)
#define FRAME_WORK_LIMIT (1 << 21)
#define ROWS 21
#define STEP_ROWS 9
#define S_BUCKET_SLOTS 0
#define S_SLOTS (S_BUCKET_SLOTS + S_BUCKETS)
#define S_AHEAD_SLOTS (S_SLOTS + UNIFORM_SLOTS)
#define S_GAP_SLOTS (S_AHEAD_SLOTS + 2)
#define COUNT_SLOTS (S_GAP_SLOTS + IS)
#define CODE_SLOTS (COUNT_SLOTS + IS)
#define ESCAPE_SLOT (CODE_SLOTS + 8 * 8)
#define THIRD_SLOTS (ESCAPE_SLOT + 1)
#define STEP_SLOTS (THIRD_SLOTS + 17 * 8)
#define BACK_SLOTS (STEP_SLOTS + STEP_ROWS * IS)
#define MASK_SLOTS (BACK_SLOTS + IS)
#define SPAN_SLOTS (MASK_SLOTS + 3)
#define SPAN_SIGN_SLOTS (SPAN_SLOTS + ROWS * IS)
#define NORMAL_SLOTS (SPAN_SIGN_SLOTS + 3)
#define PLACE_SLOTS (NORMAL_SLOTS + ROWS * IS)
#define MID_SLOTS (PLACE_SLOTS + 2)
#define MID1_SLOTS (MID_SLOTS + ROWS * IS)
#define MID2_SLOTS (MID1_SLOTS + ROWS * IS)
#define MID3_SLOTS (MID2_SLOTS + ROWS * IS)
#define MID_SIGN_SLOTS (MID3_SLOTS + ROWS * IS)
#define LATTICE_SLOT (MID_SIGN_SLOTS + 6)
#define LATTICE1_SLOTS (LATTICE_SLOT + 1)
#define LATTICE3_SLOTS (LATTICE1_SLOTS + IS)
#define CONTEXT_SLOTS (LATTICE3_SLOTS + IS)
#define LATTICE_BITS 4

// ---- arithmetic helpers ----------------------------------------------------------------
static inline i64 iabs(i64 v) { return v < 0 ? -v : v; }
static inline i32 bit_length(i64 v) {
  u64 m = (u64)iabs(v);
  return m ? 64 - __builtin_clzll(m) : 0;
}
static inline i64 floor_div(i64 a, i64 b) { // b > 0
  i64 q = a / b;
  if ((a % b) != 0 && (a < 0)) q--;
  return q;
}
static inline i32 sign_context(i64 v) { return v > 0 ? 1 : v < 0 ? 2 : 0; }
static inline i64 sgn(i64 v) { return (v > 0) - (v < 0); }
static void shift_to(i64 *values, i32 bits) {
  i64 big = iabs(values[0]);
  if (iabs(values[1]) > big) big = iabs(values[1]);
  if (iabs(values[2]) > big) big = iabs(values[2]);
  if (big < ((i64)1 << bits)) return;
  i32 shift = bit_length(big) - bits; // floor division by 2^shift
  for (int d = 0; d < 3; d++) values[d] >>= shift;
}
static inline i64 round_div(i64 num, i64 den) {
  if (den < 0) { num = -num; den = -den; }
  return floor_div(2 * num + den, 2 * den);
}
static inline i32 dominant(const i64 *v) {
  i32 k = 0;
  for (int d = 1; d < 3; d++) if (iabs(v[d]) > iabs(v[k])) k = d;
  return k;
}
static inline i64 decode_value(i32 magnitude_slots, i32 sign_slot) {
  i64 m = integer(magnitude_slots);
  return m != 0 && bit(sign_slot) ? -m : m;
}

// ---- the state (SplitState) ------------------------------------------------------------
static i32 n_base, n_full, f_full, qmax;
static i32 *faces;   // 3 f_full: the received level's faces
static i32 *fan;     // FAN_BLOCK n_full: count, spill offset, position, stamp, corners
// A vertex's grid position, and after it its stamp (a pointer into its block). A set of
// distinct neighbours is made by stamping them, in place of a search of the set for
// each: the stamp sits beside the position that the set's user reads next.
static inline i32 *q_of(i32 v) { return fan + FAN_BLOCK * v + FAN_Q; }
static i32 stamps;
static i32 new_stamp(void) {
  if (stamps == 0x7fffffff) { for (i32 v = 0; v < n_full; v++) q_of(v)[STAMP] = 0; stamps = 0; }
  return ++stamps;
}
static i32 *spill; static u32 spill_len, spill_end;
static i32 *cs, *after_, *before_, *nb, *open_, *ys, *visits; static u8 *mark; static double *keys;
static u32 scratch;  // room of the corner buffers
static i32 nc, nn, keys_for;
// outputs: as ProgressiveLevels holds them
static i32 *out_faces, *split_vertex_out, *deltas_out, *level_faces, *relabel_offsets, *relabel_faces;
static u32 relabel_len;

static inline i32 corners_of(i32 v, i32 **list) {
  i32 block = FAN_BLOCK * v;
  i32 spilled = fan[block + 1];
  *list = spilled ? spill + spilled : fan + block + FAN_CORNERS;
  return fan[block];
}
static i32 respill(i32 block, i32 from, i32 n) {
  i32 capacity = 2 * (n > FAN_INLINE ? n : FAN_INLINE);
  u32 at = spill_end + 1;
  if (at + capacity > spill_len) {
    u32 size = spill_len;
    while (size < at + capacity) size *= 2;
    i32 *grown = take(4 * size);
    if (!grown) FAIL_V(E_MEMORY, 0);
    __builtin_memcpy(grown, spill, 4 * spill_len);
    spill = grown; spill_len = size;
  }
  spill[at - 1] = capacity;
  if (from == 0) __builtin_memcpy(spill + at, fan + block + FAN_CORNERS, 4 * n);
  else __builtin_memmove(spill + at, spill + from, 4 * n);
  spill_end = at + capacity;
  fan[block + 1] = at;
  return at;
}
static void link(i32 v, i32 c) {
  i32 block = FAN_BLOCK * v;
  i32 n = fan[block];
  i32 at = fan[block + 1];
  if (at == 0 && n < FAN_INLINE) { fan[block + FAN_CORNERS + n] = c; fan[block] = n + 1; return; }
  if (at == 0 || spill[at - 1] == n) { at = respill(block, at, n); if (error) return; }
  spill[at + n] = c;
  fan[block] = n + 1;
}
// a[0..n) ascending: by insertion for a ring's few entries, else a heap sort (refine.js
// uses the typed array's sort there: the same order, the values being numbers)
#define SORT_PREFIX(name, type)                                                          \
  static void name(type *a, i32 n) {                                                     \
    if (n <= 32) {                                                                       \
      for (i32 i = 1; i < n; i++) {                                                      \
        type v = a[i]; i32 j = i - 1;                                                    \
        while (j >= 0 && a[j] > v) { a[j + 1] = a[j]; j--; }                             \
        a[j + 1] = v;                                                                    \
      }                                                                                  \
      return;                                                                            \
    }                                                                                    \
    for (i32 end = n, start = n / 2 - 1;;) {                                             \
      i32 root;                                                                          \
      if (start >= 0) root = start--;                                                    \
      else { if (--end <= 0) return; type t = a[0]; a[0] = a[end]; a[end] = t; root = 0; } \
      for (;;) {                                                                         \
        i32 child = 2 * root + 1;                                                        \
        if (child >= end) break;                                                         \
        if (child + 1 < end && a[child + 1] > a[child]) child++;                         \
        if (a[root] >= a[child]) break;                                                  \
        type t = a[root]; a[root] = a[child]; a[child] = t; root = child;                \
      }                                                                                  \
    }                                                                                    \
  }
SORT_PREFIX(sort_prefix_i32, i32)
SORT_PREFIX(sort_prefix_f64, double)
static i32 grow(u32 degree) {
  i32 *ncs = take(4 * degree);
  if (!ncs) FAIL_V(E_MEMORY, 0);
  __builtin_memcpy(ncs, cs, 4 * scratch);
  cs = ncs;
  after_ = take(4 * degree); before_ = take(4 * degree); nb = take(8 * degree);
  mark = take(degree); open_ = take(4 * degree); ys = take(4 * degree); keys = take(8 * degree);
  visits = take(4 * degree);
  if (!after_ || !before_ || !nb || !mark || !open_ || !ys || !keys || !visits) FAIL_V(E_MEMORY, 0);
  scratch = degree;
  return 1;
}
static void gather(i32 s) {
  i32 *list;
  i32 n = corners_of(s, &list);
  if ((u32)n > scratch) { if (!grow(2 * (u32)n)) return; corners_of(s, &list); }
  for (i32 q = 0; q < n; q++) cs[q] = list[q];
  sort_prefix_i32(cs, n);
  for (i32 q = 0; q < n; q++) {
    i32 c = cs[q], f = c - c % 3, j = c - f;
    after_[q] = faces[f + (j + 1) % 3];
    before_[q] = faces[f + (j + 2) % 3];
  }
  i32 stamp = new_stamp(), m = 0;
  for (i32 q = 0; q < n; q++) {
    i32 a = after_[q], b = before_[q];
    // Without a branch on whether the vertex is new to the set: each neighbour comes
    // twice (after one corner, before the next), so the outcome is a coin toss.
    i32 *pa = q_of(a) + STAMP;
    i32 new_a = (a != s) & (*pa != stamp);
    *pa = new_a ? stamp : *pa;
    nb[m] = a; m += new_a;
    i32 *pb = q_of(b) + STAMP;
    i32 new_b = (b != s) & (*pb != stamp);
    *pb = new_b ? stamp : *pb;
    nb[m] = b; m += new_b;
  }
  if (m <= SMALL_SET) {
    // Distinct values: each one's rank is how many are smaller, counted without a
    // branch; the set goes to its sorted places through a copy.
    i32 held[SMALL_SET];
    for (i32 q = 0; q < m; q++) held[q] = nb[q];
    for (i32 q = 0; q < m; q++) {
      i32 rank = 0, v = held[q];
      for (i32 r = 0; r < m; r++) rank += held[r] < v;
      nb[rank] = v;
    }
  } else sort_prefix_i32(nb, m);
  nn = m;
  nc = n;
}
static void fan_keys(i32 forward) {
  if (keys_for == forward) return;
  keys_for = forward;
  i32 *sides = forward ? before_ : after_;
  for (i32 q = 0; q < nc; q++) keys[q] = (double)sides[q] * nc + q;
  sort_prefix_f64(keys, nc); // JS sorts past 32 with the typed array's sort: same ascending order
}
static i32 fan_next(u8 *used, i32 y) {
  i32 lo = 0, hi = nc;
  double key = (double)y * nc;
  while (lo < hi) { i32 mid = (lo + hi) >> 1; if (keys[mid] < key) lo = mid + 1; else hi = mid; }
  for (; lo < nc && keys[lo] < ((double)y + 1) * nc; lo++) {
    i32 q = (i32)(keys[lo] - key);
    if (!used[q]) return q;
  }
  return -1;
}
// The split's last walk: where it started, which way, the corners it took in order
// (visits) and whether it ended at its stop (else for want of an open corner).
static i32 walked_from, walked_forward, walked_steps, walked_to_stop;
static i32 walk(i32 start, i32 forward, i32 stop) {
  i32 *sides = forward ? before_ : after_;
  i32 *steps = forward ? after_ : before_;
  for (i32 q = 0; q < nc; q++) mark[q] = 0;
  i32 y = start, m = 0, taken = 0, to_stop = 0;
  // Few corners are scanned for the first open one at y (the sides of those taken
  // overwritten: vertices are >= 0); more are looked up in the fan's keys.
  i32 scan = nc <= FAN_SCAN;
  if (scan) for (i32 q = 0; q < nc; q++) open_[q] = sides[q];
  else fan_keys(forward);
  for (i32 step = 0; step < nc; step++) {
    i32 q;
    if (scan) {
      q = -1; // without a branch on where it is
      for (i32 r = nc - 1; r >= 0; r--) q = open_[r] == y ? r : q;
      if (q >= 0) open_[q] = -1;
    } else {
      q = fan_next(mark, y);
    }
    if (q < 0) break;
    mark[q] = 1; y = steps[q];
    visits[taken++] = q;
    if (y == stop) { to_stop = 1; break; }
    ys[m++] = y;
  }
  walked_from = start; walked_forward = forward; walked_steps = taken; walked_to_stop = to_stop;
  return m;
}
// The fan from wing xl forward to wing xr. The second wing's walk (the split's first)
// went forward from xl too in nearly every split, and took the same corners as this one
// until one of them stopped: its visits give this walk, unless it stopped at xl before
// reaching xr (this one would go on).
static void predict(i32 xl, i32 xr) {
  if (xl >= 0 && walked_steps > 0 && walked_from == xl && walked_forward) {
    for (i32 q = 0; q < nc; q++) mark[q] = 0;
    for (i32 p = 0; p < walked_steps; p++) {
      i32 q = visits[p];
      mark[q] = 1;
      if (after_[q] == xr) return;
    }
    if (!walked_to_stop) return;
  }
  if (xl >= 0) walk(xl, 1, xr);
  else if (xr >= 0) walk(xr, 0, -1);
  else for (i32 q = 0; q < nc; q++) mark[q] = 0;
}
typedef struct { i64 spread[3]; i64 normal[3]; i64 laplace[3]; i64 bulge; } Shape;
static void ring_shape(i32 s, Shape *shape) {
  i32 *q = fan + FAN_Q;
  i32 sx = q[FAN_BLOCK * s], sy = q[FAN_BLOCK * s + 1], sz = q[FAN_BLOCK * s + 2];
  i32 bits = 0;
  i64 ax = 0, ay = 0, az = 0, lx = 0, ly = 0, lz = 0;
  for (i32 j = 0; j < nn; j++) {
    i32 w = FAN_BLOCK * nb[j];
    i32 ox = q[w] - sx, oy = q[w + 1] - sy, oz = q[w + 2] - sz;
    lx += ox; ly += oy; lz += oz;
    i32 bx = ox < 0 ? -ox : ox, by = oy < 0 ? -oy : oy, bz = oz < 0 ? -oz : oz;
    ax += bx; ay += by; az += bz;
    bits |= bx | by | bz;
  }
  shape->spread[0] = nn ? ax / nn : 0;
  shape->spread[1] = nn ? ay / nn : 0;
  shape->spread[2] = nn ? az / nn : 0;
  i32 shift = bit_length(bits) - DIFF_BITS;
  if (shift < 0) shift = 0;
  i64 nx = 0, ny = 0, nz = 0;
  for (i32 i = 0; i < nc; i++) {
    i32 u = FAN_BLOCK * after_[i], w = FAN_BLOCK * before_[i];
    i64 ux = (q[u] - sx) >> shift, uy = (q[u + 1] - sy) >> shift, uz = (q[u + 2] - sz) >> shift;
    i64 wx = (q[w] - sx) >> shift, wy = (q[w + 1] - sy) >> shift, wz = (q[w + 2] - sz) >> shift;
    nx += uy * wz - uz * wy; ny += uz * wx - ux * wz; nz += ux * wy - uy * wx;
  }
  shape->normal[0] = nx; shape->normal[1] = ny; shape->normal[2] = nz;
  shift_to(shape->normal, NORMAL_BITS);
  shape->laplace[0] = lx; shape->laplace[1] = ly; shape->laplace[2] = lz;
  shift_to(shape->laplace, LAPLACE_BITS);
  shape->bulge = sgn(shape->laplace[0] * shape->normal[0] + shape->laplace[1] * shape->normal[1] + shape->laplace[2] * shape->normal[2]);
}
static i32 ring_sum(i32 v, i32 other, i64 *total) {
  i32 *list;
  i32 n = corners_of(v, &list);
  i32 stamp = new_stamp(), count = 0;
  i64 x = 0, y = 0, z = 0;
  for (i32 i = 0; i < n; i++) {
    // The corner's own vertex is v: only the face's two others can join the set (both
    // are still checked against v, for a face that holds it twice).
    i32 c = list[i], f = c - c % 3, j = c - f;
    i32 after = f + (j == 2 ? 0 : j + 1), before = f + (j == 0 ? 2 : j - 1);
    for (int k = 0; k < 2; k++) {
      i32 w = faces[k ? before : after];
      i32 *p = q_of(w);
      i32 take_it = (w != v) & (w != other) & (p[STAMP] != stamp); // as in gather
      i64 keep = -(i64)take_it;
      p[STAMP] = take_it ? stamp : p[STAMP];
      count += take_it;
      x += p[0] & keep; y += p[1] & keep; z += p[2] & keep;
    }
  }
  total[0] = x; total[1] = y; total[2] = z;
  return count;
}
static void span_prediction(i32 s, i32 t, i64 *prediction) {
  i64 sum_a[3], sum_b[3];
  i32 a = ring_sum(t, s, sum_a);
  i32 b = ring_sum(s, t, sum_b);
  prediction[0] = prediction[1] = prediction[2] = 0;
  if (a == 0 || b == 0 || a > SPAN_RING_LIMIT || b > SPAN_RING_LIMIT) return;
  i64 den = (i64)(a + 1) * (b + 1) - 1;
  for (int d = 0; d < 3; d++) {
    i64 pt = floor_div(sum_a[d] * (b + 1) + sum_b[d], den);
    i64 ps = floor_div(sum_b[d] * (a + 1) + sum_a[d], den);
    prediction[d] = pt - ps;
  }
}
// Relabel face f's first corner at s to t, linking it to t; s's list is cleared of the
// moved corners once the split's relabels are done (drop_moved), in one pass rather than
// one search and shift of the list for each.
static i32 relabel(i32 f, i32 s, i32 t) {
  for (int j = 0; j < 3; j++) {
    i32 c = 3 * f + j;
    if (faces[c] == s) { faces[c] = t; link(t, c); return 1; }
  }
  return 0;
}
static void drop_moved(i32 s) {
  i32 *list;
  i32 n = corners_of(s, &list), m = 0;
  for (i32 i = 0; i < n; i++) { i32 c = list[i]; list[m] = c; m += faces[c] == s; }
  fan[FAN_BLOCK * s] = m;
}

// ---- positions (decodePositions, decodeMid) ---------------------------------------------
// A tangent value coded in units of the lattice step, in grid units; one past a few grid
// lengths is refused, as decode_connectivity refuses it.
static i64 on_lattice(i64 value, i64 step) {
  if (iabs(value) > ((i64)8 << (bit_length(qmax)))) FAIL_V(E_GRID, 0);
  return value * step;
}
static void decode_mid(const Shape *shape, const i64 *edge, i64 *mid) {
  const i64 *normal = shape->normal;
  i64 binormal[3] = {
    edge[1] * normal[2] - edge[2] * normal[1],
    edge[2] * normal[0] - edge[0] * normal[2],
    edge[0] * normal[1] - edge[1] * normal[0],
  };
  i32 k = dominant(binormal);
  if (binormal[k] == 0) {
    for (int d = 0; d < 3; d++) {
      i32 row = bit_length(edge[d]); if (row > ROWS - 1) row = ROWS - 1;
      i32 slots = MID_SLOTS + row * IS;
      mid[d] = decode_value(slots, slots + IS - 1);
    }
    return;
  }
  shift_to(binormal, NORMAL_BITS);
  i32 first = k == 0 ? 1 : 0, second = k == 2 ? 1 : 2;
  i32 swap = iabs(edge[second]) > iabs(edge[first]);
  i32 a = swap ? second : first, b = swap ? first : second;
  i64 reduced[3] = {edge[0], edge[1], edge[2]};
  shift_to(reduced, NORMAL_BITS);
  i32 length = bit_length(iabs(edge[0]) + iabs(edge[1]) + iabs(edge[2]));
  if (length > ROWS - 1) length = ROWS - 1;
  i32 row = bit_length(edge[a]); if (row > ROWS - 1) row = ROWS - 1;
  i64 big = iabs(edge[0]);
  if (iabs(edge[1]) > big) big = iabs(edge[1]);
  if (iabs(edge[2]) > big) big = iabs(edge[2]);
  i32 shift = bit_length(big) - LATTICE_BITS;
  i64 step = shift > 0 ? (i64)1 << shift : 1;
  i32 lattice = step > 1 && bit(LATTICE_SLOT);
  i32 first_slots = lattice ? LATTICE1_SLOTS : MID1_SLOTS + row * IS;
  mid[a] = decode_value(first_slots, MID_SIGN_SLOTS + sign_context(shape->bulge * normal[a]));
  if (lattice) mid[a] = on_lattice(mid[a], step);
  if (error) return;
  i64 cross = normal[b] * reduced[a] - normal[a] * reduced[b];
  i32 sign_slot = MID_SIGN_SLOTS + 3 + sign_context(shape->bulge * sgn(cross) * sgn(reduced[a]));
  i64 along = reduced[a] == 0 ? 0 : round_div(mid[a] * reduced[b], reduced[a]);
  mid[b] = decode_value(MID2_SLOTS + length * IS, sign_slot) + along;
  i32 slots = lattice ? LATTICE3_SLOTS : MID3_SLOTS + length * IS;
  i64 third = decode_value(slots, slots + IS - 1);
  if (lattice) third = on_lattice(third, step);
  mid[k] = third + round_div(-(binormal[a] * mid[a] + binormal[b] * mid[b]), binormal[k]);
}
static void decode_positions(i32 s, i32 t, const Shape *shape, i64 *edge, i64 *mid) {
  i64 prediction[3];
  span_prediction(s, t, prediction);
  if (error) return;
  const i64 *normal = shape->normal;
  i32 k = dominant(normal);
  i32 plane = normal[k] != 0;
  i32 axes[3];
  axes[0] = plane && k == 0 ? 1 : 0;
  axes[1] = plane && k == 2 ? 1 : plane ? 2 : 1;
  axes[2] = plane ? k : 2;
  for (int n = 0; n < 3; n++) {
    i32 d = axes[n];
    i32 row = bit_length(shape->spread[d]); if (row > ROWS - 1) row = ROWS - 1;
    i64 against;
    i32 magnitude, sign;
    if (plane && n == 2) {
      magnitude = NORMAL_SLOTS + row * IS; sign = magnitude + IS - 1;
      against = round_div(-(normal[axes[0]] * edge[axes[0]] + normal[axes[1]] * edge[axes[1]]), normal[d]);
    } else {
      magnitude = SPAN_SLOTS + row * IS; sign = SPAN_SIGN_SLOTS + sign_context(prediction[d]);
      against = prediction[d];
    }
    edge[d] = decode_value(magnitude, sign) + against;
  }
  i32 placement = 0;
  if (bit(PLACE_SLOTS)) placement = 1 + bit(PLACE_SLOTS + 1);
  if (placement == 0) decode_mid(shape, edge, mid);
  if (error) return;
  for (int axis = 0; axis < 3; axis++) {
    i64 old = q_of(s)[axis];
    i64 e = edge[axis];
    if (placement == 1) mid[axis] = old;
    else if (placement == 2) mid[axis] = old - e;
    else mid[axis] = (2 * (old + mid[axis]) + (e & 1) - e) / 2;
    i64 a = mid[axis];
    if (!(a >= 0 && a <= qmax && a + e >= 0 && a + e <= qmax)) FAIL(E_GRID);
  }
}

// ---- the wedge side ---------------------------------------------------------------------
// For a mesh with wedges, each split calls out to the page's wedges.js
// (WedgeLevels.decodeSplit) once its faces are linked and before its positions, where
// refine.js calls it. That reads this state (faces, cs, the corner lists) through the
// exports below, and refuses a frame by throwing: the throw unwinds through qem_decode,
// and the levels take no more frames.
__attribute__((import_module("env"), import_name("wedge_split")))
void wedge_split(i32 i, i32 s, i32 t, i32 nc, i32 first_face, i32 face);
static i32 with_wedges;

// ---- reads ahead -------------------------------------------------------------------------
// A large level's blocks and faces are out of cache (dragon's 40 MB), and a split waits on
// three rounds of misses: its vertex's block, the faces of its corners, their vertices'
// blocks. The frame's split vertices are known ahead (decoded first), and WebAssembly has
// no prefetch, so each split reads ahead into a sink: the block of the split three on,
// the faces of the one two on (its block read a split ago), the blocks of the next one's
// ring (its faces read a split ago). The reads come just before the positions' decoding,
// arithmetic on the coder's state that runs while they wait. Dragon in node: 0.90-0.93x
// its time. A mesh whose blocks and faces fit in a cache (bunny's 3 MB, igea's 12 MB)
// gained nothing (1-5 % slower, within the runs' noise), so only one past
// READ_AHEAD_BYTES reads ahead. What is read is only summed: a split in between that
// changes those lists (or a vertex not made yet, whose list is empty) costs a useless
// read, never a wrong one, and every index read is in range as the decoder keeps it.
#ifndef READ_AHEAD_BYTES // the tests build a variant that reads ahead on any mesh
#define READ_AHEAD_BYTES (24u << 20)
#endif
static i32 read_ahead;
static volatile u32 sink;
static inline void touch_ahead(const i32 *sv, i32 i, i32 k) {
  u32 sum = 0;
  i32 *list;
  if (i + 3 < k) sum += (u32)fan[FAN_BLOCK * sv[i + 3]];
  if (i + 2 < k) {
    i32 n = corners_of(sv[i + 2], &list);
    for (i32 q = 0; q < n && q < FAN_SCAN; q++) sum += (u32)faces[list[q] - list[q] % 3];
  }
  if (i + 1 < k) {
    i32 n = corners_of(sv[i + 1], &list);
    for (i32 q = 0; q < n && q < FAN_SCAN; q++) {
      i32 f = list[q] - list[q] % 3;
      for (int j = 0; j < 3; j++) sum += (u32)fan[FAN_BLOCK * faces[f + j]];
    }
  }
  sink += sum;
}

// ---- the API -------------------------------------------------------------------------------
// init: buffers for the full mesh; returns the offset of the base's positions (3 n_base
// int32) and faces (3 f_base int32), which the caller fills before link_base.
static i32 *base_q, *base_faces;
static i32 f_base_count;
i32 qem_init(i32 nb_, i32 nfull, i32 ffull, i32 fbase, i32 bits, i32 wedges) {
  n_base = nb_; n_full = nfull; f_full = ffull; f_base_count = fbase; qmax = (i32)((1u << bits) - 1u);
  with_wedges = wedges;
  error = 0;
  // The largest buffers past 2 GiB cannot be had in wasm32's memory, and their sizes
  // would wrap as 32-bit products: no room.
  if (n_base < 0 || n_full < n_base || f_full < fbase || fbase < 0 ||
      (u64)n_full * 4 * FAN_BLOCK >= (1ull << 31) || (u64)f_full * 12 >= (1ull << 31))
    return 0;
  faces = take(12u * f_full); fan = take(4u * FAN_BLOCK * n_full);
  read_ahead = 12u * f_full + 4u * FAN_BLOCK * n_full >= READ_AHEAD_BYTES;
  spill_len = 1024; spill = take(4 * spill_len); spill_end = 1;
  scratch = 16; cs = take(64); after_ = take(64); before_ = take(64); nb = take(128); mark = take(16);
  open_ = take(64); ys = take(64); keys = take(128); visits = take(64);
  stamps = 0;
  probs = take(2 * CONTEXT_SLOTS);
  i32 n_splits = n_full - n_base;
  out_faces = take(12u * f_full);
  split_vertex_out = take(4u * (n_splits + 1)); deltas_out = take(24u * (n_splits + 1));
  level_faces = take(4u * (n_splits + 1)); relabel_offsets = take(4u * (n_splits + 1));
  relabel_len = 2u * (n_splits > 8 ? n_splits : 8); relabel_faces = take(4 * relabel_len);
  base_q = take(12u * (n_base > 0 ? n_base : 1)); base_faces = take(12u * (fbase > 0 ? fbase : 1));
  if (!faces || !fan || !spill || !cs || !after_ || !before_ || !nb || !mark || !open_ || !ys ||
      !keys || !visits || !probs || !out_faces || !split_vertex_out || !deltas_out || !level_faces ||
      !relabel_offsets || !relabel_faces || !base_q || !base_faces)
    return 0;
  return 1;
}
i32 *qem_base_positions(void) { return base_q; }
i32 *qem_base_faces(void) { return base_faces; }
i32 qem_link_base(void) {
  for (i32 v = 0; v < n_base; v++) for (int d = 0; d < 3; d++) q_of(v)[d] = base_q[3 * v + d];
  for (i32 c = 0; c < 3 * f_base_count; c++) {
    i32 v = base_faces[c];
    if (v < 0 || v >= n_base) return E_BASE;
    faces[c] = v; out_faces[c] = v;
    link(v, c);
    if (error) return error;
  }
  level_faces[0] = f_base_count;
  return 0;
}
i32 *qem_split_vertex(void) { return split_vertex_out; }
i32 *qem_deltas(void) { return deltas_out; }
i32 *qem_level_faces(void) { return level_faces; }
i32 *qem_relabel_offsets(void) { return relabel_offsets; }
i32 *qem_relabel_faces(void) { return relabel_faces; }
i32 *qem_out_faces(void) { return out_faces; }
i32 *qem_faces(void) { return faces; }
i32 *qem_fan(void) { return fan; }
i32 qem_fan_ints(void) { return FAN_BLOCK * n_full; }
// where the corner lists that outgrew their blocks are, and the sorted corners of the
// split being decoded (both move when they grow)
i32 *qem_spill(void) { return spill; }
i32 qem_spill_ints(void) { return (i32)spill_len; }
i32 *qem_cs(void) { return cs; }
i32 qem_cs_ints(void) { return (i32)scratch; }
static u8 *coded_room; static u32 coded_len_room;
// room for a frame's coded bytes, reused from frame to frame; 0 when memory ran out
u8 *qem_coded(u32 n) {
  if (n > coded_len_room) { coded_room = take(n); coded_len_room = coded_room ? n : 0; }
  return coded_room;
}

static void reserve_relabels(u32 count) {
  if (count <= relabel_len) return;
  u32 size = relabel_len;
  while (size < count) size *= 2;
  i32 *grown = take(4 * size);
  if (!grown) FAIL(E_MEMORY);
  __builtin_memcpy(grown, relabel_faces, 4 * relabel_len);
  relabel_faces = grown; relabel_len = size;
}

// decode one frame's splits (ProgressiveLevels.decodeSplits): returns 0 or an error code
i32 qem_decode(const u8 *coded, u32 coded_len, i32 n_from, i32 k, i32 faces_from, i32 n_new_faces, i32 fresh) {
  error = 0;
  if (fresh) for (i32 i = 0; i < CONTEXT_SLOTS; i++) probs[i] = HALF;
  coder_start(coded, coded_len);
  i32 first = n_from - n_base;
  i32 relabel_at = relabel_offsets[first];
  i32 face = faces_from, face_end = faces_from + n_new_faces;
  i32 *sv = split_vertex_out + first;
  // every split's s first (decodeSplitVertices)
  {
    i32 previous = -1, was_ahead = 0;
    for (i32 i = 0; i < k; i++) {
      if (broken) return E_SHORT;
      i32 t = n_from + i;
      error_split = t;
      if (t < 1) return E_NOT_YET;
      i64 s;
      if (bit(S_AHEAD_SLOTS + was_ahead)) {
        was_ahead = 1;
        s = previous + 1 + integer(S_GAP_SLOTS);
        if (s >= t) return E_NOT_YET;
      } else {
        was_ahead = 0;
        i64 n = previous + 1;
        i64 bucket = tree(S_BUCKET_SLOTS, S_BUCKET_BITS);
        i64 lo = (bucket * n + S_BUCKETS - 1) / S_BUCKETS, hi = ((bucket + 1) * n + S_BUCKETS - 1) / S_BUCKETS;
        if (hi <= lo) return E_NOT_YET;
        s = lo + uniform(S_SLOTS, hi - lo);
      }
      previous = (i32)s;
      sv[i] = (i32)s;
    }
  }
  i64 corners_walked = 0;
  Shape shape;
  i64 edge[3], mid[3];
  for (i32 i = 0; i < k; i++) {
    if (broken) return E_SHORT;
    i32 t = n_from + i, s = sv[i];
    error_split = t;
    gather(s);
    if (error) return error;
    corners_walked += nc;
    if (i > 0 && corners_walked > FRAME_WORK_LIMIT) { error_value = FRAME_WORK_LIMIT; return E_WORK; }
    keys_for = -1;
    walked_steps = 0; // no walk yet this split
    ring_shape(s, &shape);
    i64 count = integer(COUNT_SLOTS);
    if (count > face_end - face) return E_COUNTS;
    i32 xl = -1, xr = -1, first_forward = 0, walk_length = -1, first_new = face, previous = 7;
    for (i64 j = 0; j < count; j++, face++) {
      i32 fcode = tree(CODE_SLOTS + 8 * previous, 3);
      previous = fcode;
      i32 f = 3 * face;
      if (fcode == EXPLICIT_FACE) {
        for (int c = 0; c < 3; c++) {
          i64 b = integer(BACK_SLOTS);
          if (b > t) return E_NO_VERTEX;
          faces[f + c] = (i32)(t - b);
        }
        continue;
      }
      if (fcode > EXPLICIT_FACE) { error_value = fcode; return E_FACE_CODE; }
      i32 forward = fcode < 3;
      i32 wing = xl >= 0 || xr >= 0;
      i32 x = -1;
      if (wing && walk_length < 0 && forward != first_forward) {
        i32 start = xl >= 0 ? xl : xr;
        walk_length = walk(start, first_forward, start);
        if (walk_length > 0) {
          i32 row = walk_length < STEP_ROWS - 1 ? walk_length : STEP_ROWS - 1;
          i64 step = integer(STEP_SLOTS + row * IS);
          if (step > walk_length) return E_THIRD;
          if (step < walk_length) x = ys[step];
        }
      }
      if (!wing) first_forward = forward;
      if (x >= 0) {
      } else if (bit(ESCAPE_SLOT)) {
        i64 b = integer(BACK_SLOTS);
        if (b > t) return E_NO_VERTEX;
        x = (i32)(t - b);
      } else if (nn > 0) {
        i32 n_index = nn < ESCAPE ? nn : ESCAPE;
        x = nb[uniform(THIRD_SLOTS + (n_index < 16 ? n_index : 16) * 8, n_index)];
      } else {
        return E_THIRD;
      }
      i32 rotation = fcode % 3;
      faces[f + rotation] = forward ? s : t;
      faces[f + (rotation + 1) % 3] = forward ? t : s;
      faces[f + (rotation + 2) % 3] = x;
      if (forward && xl < 0) xl = x;
      if (!forward && xr < 0) xr = x;
    }
    for (i32 c = 3 * first_new; c < 3 * face; c++) out_faces[c] = faces[c];
    predict(xl, xr);
    if (nc && bit(MASK_SLOTS)) for (i32 j = 0; j < nc; j++) mark[j] = (u8)bit(MASK_SLOTS + 1 + mark[j]);
    reserve_relabels((u32)(relabel_at + nc));
    if (error) return error;
    for (i32 j = 0; j < nc; j++) {
      if (!mark[j]) continue;
      i32 f = cs[j] / 3;
      if (!relabel(f, s, t)) return E_RELABEL;
      if (error) return error;
      relabel_faces[relabel_at++] = f;
    }
    drop_moved(s);
    for (i32 c = 3 * first_new; c < 3 * face; c++) { link(faces[c], c); if (error) return error; }
    if (with_wedges) wedge_split(i, s, t, nc, first_new, face);
    if (read_ahead) touch_ahead(sv, i, k);
    decode_positions(s, t, &shape, edge, mid);
    if (error) return error;
    for (int axis = 0; axis < 3; axis++) {
      i32 old = q_of(s)[axis];
      i32 a = (i32)mid[axis];
      q_of(s)[axis] = a;
      q_of(t)[axis] = a + (i32)edge[axis];
      deltas_out[6 * (first + i) + axis] = a - old;
      deltas_out[6 * (first + i) + 3 + axis] = a + (i32)edge[axis] - old;
    }
    level_faces[first + i + 1] = face;
    relabel_offsets[first + i + 1] = relabel_at;
  }
  if (broken) return E_SHORT;
  if (position != coded_len) return E_TRAILING;
  if (face != face_end) return E_COUNTS;
  return 0;
}
