"""The runtime's lighter Taichi front end (taichi_ndf.runtime, issue 28): the class test of
@ti.kernel/@ti.func without `inspect.getframeinfo` (a scan of sys.modules per decorator), and
source positions of compiled AST nodes without Taichi's text-wrapped, underlined excerpt; the
same answers, the error messages still naming file, line, function and source line."""

import importlib
import inspect
import textwrap

import pytest

from taichi_ndf import runtime
from taichi_ndf.runtime import ti


def _count_calls(monkeypatch, owner, name: str) -> list:
    calls = []
    original = getattr(owner, name)

    def counted(*args, **kwargs):
        calls.append(name)
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, counted)
    return calls


def _taichi_only():
    if runtime.current().backend != "taichi":
        pytest.skip("quadrants builds (and memoises) its source positions its own way")


def test_the_class_test_of_decorators_reads_no_frame_info(taichi_runtime, monkeypatch):
    calls = _count_calls(monkeypatch, inspect, "getframeinfo")

    @ti.kernel
    def twice(x: ti.f64) -> ti.f64:
        return 2 * x

    @ti.data_oriented
    class Scaled:
        def __init__(self, factor: float):
            self.factor = factor

        @ti.kernel
        def apply(self, x: ti.f64) -> ti.f64:
            return self.factor * x

    assert calls == []
    assert not twice._is_classkernel and Scaled.apply._is_classkernel
    assert twice(1.5) == 3.0 and Scaled(3.0).apply(1.5) == 4.5


def test_compiling_formats_no_wrapped_source_excerpts(taichi_runtime, monkeypatch):
    _taichi_only()
    excerpts = []  # Taichi wraps its excerpts at 80 columns (the source it reads at 9999)
    wrap = textwrap.TextWrapper.wrap
    monkeypatch.setattr(textwrap.TextWrapper, "wrap", lambda self, text: (
        excerpts.append(text) if self.width == 80 else None, wrap(self, text))[1])

    @ti.kernel
    def cubed(x: ti.f64) -> ti.f64:
        y = x * x
        return y * x

    assert cubed(2.0) == 8.0
    assert excerpts == []


def test_a_compile_error_names_file_line_function_and_source(taichi_runtime):
    @ti.kernel
    def broken(x: ti.f64) -> ti.f64:
        return x * undefined_name  # noqa: F821

    with pytest.raises(Exception) as error:
        broken(1.0)
    message = str(error.value)
    line = inspect.getsourcelines(broken)[1] + 2
    assert f'{__file__}", line {line}, in broken' in message
    assert "return x * undefined_name" in message


def test_debug_gets_taichis_own_positions_back(taichi_runtime):
    _taichi_only()
    backend = runtime.current().backend
    context = importlib.import_module(f"{backend}.lang.ast.ast_transformer_utils") \
        .ASTTransformerContext
    quick = context.get_pos_info
    try:
        runtime._source_positions(backend, full=True)
        assert context.get_pos_info is runtime._FULL_POSITIONS[backend]
        assert context.get_pos_info is not quick
    finally:
        runtime._source_positions(backend, full=runtime.current().debug)


def test_a_functions_source_is_read_once_however_often_it_is_compiled(taichi_runtime,
                                                                      monkeypatch):
    _taichi_only()
    reads = []
    getsourcelines = inspect.getsourcelines
    monkeypatch.setattr(inspect, "getsourcelines", lambda obj: (
        reads.append(getattr(obj, "__name__", obj)), getsourcelines(obj))[1])

    @ti.func
    def square(x):
        return x * x

    @ti.kernel
    def fourth(x: ti.f64) -> ti.f64:
        return square(square(x))

    @ti.kernel
    def sum_of_squares(x: ti.f64, y: ti.f64) -> ti.f64:
        return square(x) + square(y)

    assert fourth(2.0) == 16.0 and sum_of_squares(1.0, 2.0) == 5.0
    assert reads.count("square") == 1
