"""A compiled kernel does not keep the arrays of the call that compiled it
(`runtime._compile_arguments_released`: Taichi's compile context holds them in a reference
cycle, alive until the cyclic collector's next full pass)."""

import gc
import weakref

import torch


def test_the_compiling_calls_arrays_are_freed_when_dropped(taichi_runtime):
    from taichi_ndf.runtime import ti

    @ti.kernel
    def doubled(a: ti.types.ndarray(), out: ti.types.ndarray()):  # a kernel new to this process
        for i in range(a.shape[0]):
            out[i] = 2 * a[i]

    a = torch.arange(1000, dtype=torch.float64)
    out = torch.empty_like(a)
    gc.disable()  # only reference counting frees them: no collector pass in between
    try:
        doubled(a, out)
        assert torch.equal(out, 2 * a)
        alive = weakref.ref(a), weakref.ref(out)
        del a, out
        assert [ref() is None for ref in alive] == [True, True]
    finally:
        gc.enable()
    again = torch.ones(3, dtype=torch.float64)  # and the kernel still runs
    result = torch.empty_like(again)
    doubled(again, result)
    assert torch.equal(result, 2 * again)
