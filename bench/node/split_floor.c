// The floor of split_floor.mjs (its decodeFloor, the same work line by line) in C, for
// WebAssembly: bench.split_floor builds it with `python -m ziglang cc --target=
// wasm32-freestanding` when the dev extra's ziglang is there. The caller places every
// array in the module's imported memory and passes their offsets; faces is 0 for the
// floor without a face index buffer. Returns the coded bytes read.
#include <stdint.h>
#define BLOCK 32
#define NEIGHBOURS 4
#define ROOM 14
#define FACES 16
#define PROB_BITS 12
#define PROB_SCALE (1u << PROB_BITS)
#define RANS_LOW (1u << 23)

int32_t floor_decode(int32_t nBase, int32_t nFull, int32_t fBase, int32_t fFull, int32_t symbols,
    const int32_t *baseQ, const int32_t *baseFaces, const int32_t *splitVertex,
    const int32_t *movedOffsets, const int32_t *moved, const int32_t *wingOffsets, const int32_t *wings,
    const int32_t *relabelOffsets, const int32_t *relabelFaces, const int32_t *newFaces, const int32_t *newFaceCounts,
    const uint8_t *coded, const uint32_t *freq, const uint32_t *cum, const uint8_t *letterAt,
    int32_t *blocks, int32_t *faces, int32_t *recordFaces, int32_t *recordNew, int32_t *deltas) {
  int32_t nSplits = nFull - nBase;
  __builtin_memset(blocks, 0, (uint32_t)BLOCK * nFull * 4);
  for (int32_t v = 0; v < nBase; v++) for (int d = 0; d < 3; d++) blocks[BLOCK * v + 1 + d] = baseQ[3 * v + d];
  if (faces) { __builtin_memset(faces, 0, (uint32_t)3 * fFull * 4); __builtin_memcpy(faces, baseFaces, (uint32_t)3 * fBase * 4); }
  uint32_t state = ((uint32_t)coded[0] << 24) | ((uint32_t)coded[1] << 16) | ((uint32_t)coded[2] << 8) | coded[3];
  const uint8_t *at = coded + 4;
  int32_t face = fBase, relabelled = 0;
  for (int32_t i = 0; i < nSplits; i++) {
    int32_t s = splitVertex[i], t = nBase + i;
    uint32_t value = 0;
    for (int k = 0; k < symbols; k++) {
      uint32_t slot = state & (PROB_SCALE - 1);
      uint32_t letter = letterAt[slot];
      state = freq[letter] * (state >> PROB_BITS) + slot - cum[letter];
      while (state < RANS_LOW) state = (state << 8) | *at++;
      value = (value * 5 + letter) & 0xffffff;
    }
    int32_t *bs = blocks + BLOCK * s, *bt = blocks + BLOCK * t;
    int32_t degree = bs[0], tDegree = 0;
    for (int32_t r = movedOffsets[i]; r < movedOffsets[i + 1]; r++) {
      int32_t v = moved[r];
      int32_t *bv = blocks + BLOCK * v;
      int32_t n = bv[0] < ROOM ? bv[0] : ROOM;
      for (int32_t q = 0; q < n; q++) if (bv[NEIGHBOURS + q] == s) { bv[NEIGHBOURS + q] = t; break; }
      if (tDegree < ROOM) bt[NEIGHBOURS + tDegree] = v;
      tDegree++;
    }
    int32_t w[3] = {0, 0, 0};
    for (int32_t r = wingOffsets[i]; r < wingOffsets[i + 1]; r++) {
      int32_t *bx = blocks + BLOCK * wings[r];
      int32_t n = bx[0];
      if (n < ROOM) bx[NEIGHBOURS + n] = t;
      bx[0] = n + 1;
      w[0] += bx[1]; w[1] += bx[2]; w[2] += bx[3];
    }
    bt[0] = tDegree + 1;
    degree = degree - tDegree + wingOffsets[i + 1] - wingOffsets[i] + 1;
    bs[0] = degree;
    if (degree >= 1 && degree <= ROOM) bs[NEIGHBOURS + degree - 1] = t;
    for (int32_t r = relabelOffsets[i]; r < relabelOffsets[i + 1]; r++) {
      int32_t f = relabelFaces[r];
      recordFaces[relabelled++] = f;
      bt[FACES + ((r - relabelOffsets[i]) & 15)] = f;
      if (faces) for (int j = 0; j < 3; j++) if (faces[3 * f + j] == s) { faces[3 * f + j] = t; break; }
    }
    for (int32_t j = 0; j < newFaceCounts[i]; j++, face++) for (int c = 0; c < 3; c++) {
      int32_t v = newFaces[3 * (face - fBase) + c];
      recordNew[3 * (face - fBase) + c] = v;
      if (faces) faces[3 * face + c] = v;
    }
    int32_t met = wingOffsets[i + 1] - wingOffsets[i]; if (met < 1) met = 1;
    for (int d = 0; d < 3; d++) {
      int32_t old = bs[1 + d];
      int32_t edge = (int32_t)((value >> (2 * d)) & 15) - 8 + ((w[d] / met - old) >> 3);
      int32_t a = old + (int32_t)((value >> (d + 12)) & 7) - 3;
      bs[1 + d] = a; bt[1 + d] = a + edge;
      deltas[6 * i + d] = a - old; deltas[6 * i + 3 + d] = a + edge - old;
    }
  }
  return (int32_t)(at - coded);
}
