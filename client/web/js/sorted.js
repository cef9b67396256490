// Short sorted integer arrays, as the decoders keep a ring's corners, neighbours and
// wedges: sorted in place, without allocating (refine.js, wedges.js).

/** Sort array[0..n) ascending: by insertion for the few entries of a vertex's ring (a
 * typed array's sort costs more than it sorts there), else the typed array's sort. */
export function sortPrefix(array, n) {
  if (n > 32) {
    array.subarray(0, n).sort();
    return;
  }
  for (let i = 1; i < n; i++) {
    const value = array[i];
    let j = i - 1;
    while (j >= 0 && array[j] > value) {
      array[j + 1] = array[j];
      j--;
    }
    array[j + 1] = value;
  }
}

/** values[0..n) sorted ascending, repeats dropped; returns the new length. */
export function distinctSorted(values, n) {
  sortPrefix(values, n);
  let m = 0;
  for (let q = 0; q < n; q++) if (m === 0 || values[q] !== values[m - 1]) values[m++] = values[q];
  return m;
}

/** Index of x in sorted values[0..n), or -1. */
export function findSorted(values, n, x) {
  let lo = 0;
  let hi = n;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (values[mid] < x) lo = mid + 1;
    else hi = mid;
  }
  return lo < n && values[lo] === x ? lo : -1;
}
