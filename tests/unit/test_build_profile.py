"""bench/build_profile.py: perf's sample addresses mapped to numba kernels."""

from bench.build_profile import KernelSymbol, kernel_name, read_symbols, share_by_symbol

PLACE = "_ZN8qem_core8_kernels9placement6_placeB4v156B40c8tJTIeFIjxB2IKSgI4Crv5ArrayIdLi1E"
LOOP = "_ZN8qem_core8_kernels8contract17_run_contractionsB3v86B52c8tJTIeFIjxB2E7Complex"
WRAPPER = "_ZN7cpython8qem_core8_kernels8contract17_run_contractionsB3v86B52c8tJT"


def test_kernel_names_are_module_and_function():
    assert kernel_name(PLACE) == "placement._place"
    assert kernel_name(LOOP) == "contract._run_contractions"
    assert kernel_name(WRAPPER) == "cpython wrapper of contract._run_contractions"
    assert kernel_name("NRT_MemInfo_call_dtor") == "NRT_MemInfo_call_dtor"


def test_symbols_are_placed_where_their_kernel_was_loaded():
    nm = (f"0000000000000000 0000000000000100 T {LOOP}\n"
          f"0000000000000100 0000000000000040 W {PLACE}\n"
          "0000000000000020 r .const.missing\n"
          "0000000000000008 C _ZN08NumbaEnv\n")
    symbols = read_symbols(nm, PLACE, 0x7000_0100)
    assert symbols == [KernelSymbol(0x7000_0000, 0x7000_0100, LOOP),
                       KernelSymbol(0x7000_0100, 0x7000_0140, PLACE)]
    assert read_symbols(nm, "not_there", 0x1000) == []


def test_samples_count_for_the_kernel_holding_their_address():
    symbols = [KernelSymbol(0x2000, 0x2040, PLACE), KernelSymbol(0x1000, 0x1100, LOOP)]
    samples = [(0x1000, ""), (0x10FF, ""), (0x1100, "__cos_fma"), (0x2000, ""),
               (0x203F, "x"), (0x2040, ""), (0x10, "clear_page_erms")]
    counts = share_by_symbol(samples, symbols)
    assert counts == {"contract._run_contractions": 2, "placement._place": 2,
                      "__cos_fma": 1, "[unknown]": 1, "clear_page_erms": 1}
