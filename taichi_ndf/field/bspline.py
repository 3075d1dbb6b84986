"""Uniform B-splines of degree p on one knot grid per direction: basis polynomials, refinement
masks and the Taichi kernels that evaluate the tensor-product basis jets at points.

Knots are uniform with spacing h = (hi − lo)/n over n spans and extended past the domain
(unclamped), so every span is alike. In span units t = (ξ − lo)/h the coefficient j carries
B_j(t) = N_p(t − j + p), N_p the cardinal B-spline on [0, p + 1]; on span s (t = s + u,
u ∈ [0, 1]) the p + 1 coefficients s, …, s + p act, coefficient s + a with piece p − a of N_p.
An open direction has n + p coefficients; a periodic one n, indices taken modulo n. Outside
the domain an open direction continues the polynomial of its first or last span.

Dyadic refinement (knot insertion at every midpoint) is exact: N_p(x) =
Σ_r 2⁻ᵖ C(p + 1, r) N_p(2x − r), so B_j = Σ_r 2⁻ᵖ C(p + 1, r) B'_{2j − p + r} on the halved
grid (indices modulo 2n when periodic; open fine indices outside [0, 2n + p) have no support
in the domain and are dropped).
"""

# No `from __future__ import annotations`: this module defines Taichi kernels.

import functools
import math
from fractions import Fraction

import torch

from taichi_ndf.jets import CHANNELS
from taichi_ndf.runtime import ti


@functools.cache
def piece_coefficients(degree: int) -> tuple[tuple[Fraction, ...], ...]:
    """Monomial coefficients of the basis acting on a span: row a, column k is the coefficient
    of uᵏ in piece p − a of N_p (the weight of coefficient s + a on span s); exact fractions.

    Built with the recursion N_p(x) = x/p N_{p−1}(x) + (p + 1 − x)/p N_{p−1}(x − 1), piece i
    of N_p being its polynomial on [i, i + 1] in u = x − i.
    """
    pieces = [[Fraction(1)]]  # N_0: one piece, the constant 1
    for p in range(1, degree + 1):
        def piece(i, previous=pieces):
            return previous[i] if 0 <= i < len(previous) else [Fraction(0)]

        new = []
        for i in range(p + 1):
            left, right = piece(i), piece(i - 1)
            poly = [Fraction(0)] * (p + 1)
            for k, c in enumerate(left):  # (i + u)/p · left(u)
                poly[k] += c * i / p
                poly[k + 1] += c / p
            for k, c in enumerate(right):  # (p + 1 − i − u)/p · right(u)
                poly[k] += c * (p + 1 - i) / p
                poly[k + 1] -= c / p
            new.append(poly)
        pieces = new
    return tuple(tuple(pieces[degree - a]) for a in range(degree + 1))


def basis_matrices(degree: int, dtype: torch.dtype, device) -> torch.Tensor:
    """(3, p + 1, p + 1): monomial coefficients of the span basis (`piece_coefficients`) and of
    its first and second derivatives in u, zero-padded to p + 1 columns."""
    m = torch.tensor([[float(c) for c in row] for row in piece_coefficients(degree)],
                     dtype=torch.float64)
    k = torch.arange(degree + 1, dtype=torch.float64)
    d1 = torch.zeros_like(m)
    d1[:, :-1] = m[:, 1:] * k[1:]
    d2 = torch.zeros_like(m)
    d2[:, :-1] = d1[:, 1:] * k[1:]
    return torch.stack((m, d1, d2)).to(dtype=dtype, device=device)


def refinement_1d(spans: int, degree: int, periodic: bool) -> list[tuple[int, int, float]]:
    """(fine index, coarse index, weight) of the exact dyadic refinement in one direction:
    coarse coefficients on `spans` spans -> fine coefficients on 2·spans spans."""
    coarse = spans if periodic else spans + degree
    fine = 2 * spans if periodic else 2 * spans + degree
    entries = []
    for j in range(coarse):
        for r in range(degree + 2):
            weight = math.comb(degree + 1, r) / 2**degree
            index = 2 * j - degree + r
            if periodic:
                entries.append((index % fine, j, weight))
            elif 0 <= index < fine:
                entries.append((index, j, weight))
    return entries


@functools.cache
def basis_kernel(degree: int):
    """Kernel filling index (N, (p+1)²) (an integer array) and basis (N, 6, (p+1)²) with the
    tensor-product basis jets at ξ (N, 2). grid (2, 2): (lo, h) per direction; matrices:
    `basis_matrices`.

    Contains no floating-point literal, so it computes in the dtype of its arrays.
    """
    order = degree + 1

    @ti.func
    def span(x, lo, h, spans: ti.i32, periodic: ti.i32):
        t = (x - lo) / h
        if periodic:
            t = t - spans * ti.floor(t / spans)
        s = ti.min(ti.max(ti.cast(ti.floor(t), ti.i32), 0), spans - 1)
        return s, t - s

    @ti.func
    def poly(matrices: ti.template(), which: ti.template(), a: ti.template(), u):
        acc = matrices[which, a, order - 1]
        for k in ti.static(range(order - 2, -1, -1)):
            acc = acc * u + matrices[which, a, k]
        return acc

    @ti.kernel
    def evaluate(xi: ti.types.ndarray(ndim=2), grid: ti.types.ndarray(ndim=2),
                 matrices: ti.types.ndarray(ndim=3), spans1: ti.i32, spans2: ti.i32,
                 periodic1: ti.i32, periodic2: ti.i32, index: ti.types.ndarray(ndim=2),
                 basis: ti.types.ndarray(ndim=3)):
        for i in range(xi.shape[0]):
            h1 = grid[0, 1]
            h2 = grid[1, 1]
            s1, u1 = span(xi[i, 0], grid[0, 0], h1, spans1, periodic1)
            s2, u2 = span(xi[i, 1], grid[1, 0], h2, spans2, periodic2)
            v1 = ti.Vector([poly(matrices, 0, a, u1) for a in ti.static(range(order))])
            d1 = ti.Vector([poly(matrices, 1, a, u1) for a in ti.static(range(order))]) / h1
            dd1 = ti.Vector([poly(matrices, 2, a, u1) for a in ti.static(range(order))])
            dd1 = dd1 / (h1 * h1)
            v2 = ti.Vector([poly(matrices, 0, a, u2) for a in ti.static(range(order))])
            d2 = ti.Vector([poly(matrices, 1, a, u2) for a in ti.static(range(order))]) / h2
            dd2 = ti.Vector([poly(matrices, 2, a, u2) for a in ti.static(range(order))])
            dd2 = dd2 / (h2 * h2)
            count2 = ti.select(periodic2 != 0, spans2, spans2 + order - 1)
            for a1 in ti.static(range(order)):
                j1 = s1 + a1
                if periodic1:
                    j1 = j1 % spans1
                for a2 in ti.static(range(order)):
                    j2 = s2 + a2
                    if periodic2:
                        j2 = j2 % spans2
                    c = a1 * order + a2
                    index[i, c] = j1 * count2 + j2
                    basis[i, 0, c] = v1[a1] * v2[a2]
                    basis[i, 1, c] = d1[a1] * v2[a2]
                    basis[i, 2, c] = v1[a1] * d2[a2]
                    basis[i, 3, c] = dd1[a1] * v2[a2]
                    basis[i, 4, c] = d1[a1] * d2[a2]
                    basis[i, 5, c] = v1[a1] * dd2[a2]

    return evaluate


@functools.cache
def contract_kernel(channels: int, out_dim: int):
    """Kernel out[i, ch, c] = Σ_k basis[i, ch, k] · coefficients[index[i, k], c] for the first
    `channels` jet channels: one thread per point, its (channels × out_dim) sums in registers,
    each coefficient row read once."""

    @ti.kernel
    def contract(index: ti.types.ndarray(ndim=2), basis: ti.types.ndarray(ndim=3),
                 coefficients: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=3)):
        for i in range(out.shape[0]):
            row = index[i, 0]
            acc = ti.Matrix([[basis[i, ch, 0] * coefficients[row, c]
                              for c in ti.static(range(out_dim))]
                             for ch in ti.static(range(channels))])
            for k in range(1, index.shape[1]):
                row = index[i, k]
                for ch, c in ti.static(ti.ndrange(channels, out_dim)):
                    acc[ch, c] += basis[i, ch, k] * coefficients[row, c]
            for ch, c in ti.static(ti.ndrange(channels, out_dim)):
                out[i, ch, c] = acc[ch, c]

    return contract


@functools.cache
def contract_adjoint_kernel(out_dim: int):
    """Kernel contribution[i, k, c] = Σ_ch basis[i, ch, k] · grad[i, ch, c]: what point i
    adds to the gradient of the coefficient index[i, k] (the scatter is left to the caller)."""

    @ti.kernel
    def contract_adjoint(basis: ti.types.ndarray(ndim=3), grad: ti.types.ndarray(ndim=3),
                         contribution: ti.types.ndarray(ndim=3)):
        for i in range(contribution.shape[0]):
            g = ti.Matrix([[grad[i, ch, c] for c in ti.static(range(out_dim))]
                           for ch in ti.static(range(CHANNELS))])
            for k in range(contribution.shape[1]):
                for c in ti.static(range(out_dim)):
                    acc = basis[i, 0, k] * g[0, c]
                    for ch in ti.static(range(1, CHANNELS)):
                        acc += basis[i, ch, k] * g[ch, c]
                    contribution[i, k, c] = acc

    return contract_adjoint
