"""The neural deformation field: a SIREN MLP with exact jets and hand-written weight gradients.

Layers, in the standard SIREN formulation (Sitzmann et al. 2020) with ω₀ in every sine layer:

    h₁ = sin(ω₀ (W₁ x + b₁)),  h_l = sin(ω₀ (W_l h_{l-1} + b_l)),  u = s_out (W_out h_L + b_out)

x are the encoded inputs (``encoding.py``), s_out = ``output_scale``. Initialisation: first layer
W ~ U(-1/in, 1/in); hidden layers W ~ U(-√(6/in)/ω₀, √(6/in)/ω₀); sine-layer biases
U(-1/√in, 1/√in) (torch's Linear default, kept by SIREN); output layer W ~ U(-c, c) with
c = 10⁻³ √(6/in), bias 0, so the initial displacement has an RMS of ~10⁻³ output_scale and the
solver starts near the undeformed state.

Jets propagate channel-major, (6, N, width): per layer one GEMM on all six channels stacked
(the bias enters the value channel only), then the sine-jet activation. Backward: per layer
dW = Σ_c dA_cᵀ H_c as one GEMM, db = Σ_n dA_0, dH = dA W, then the activation adjoint. No
torch autograd is involved.
"""

from __future__ import annotations

import logging
import math

import torch

from taichi_ndf.field.activation import sine_jets, sine_jets_adjoint
from taichi_ndf.field.config import FieldConfig
from taichi_ndf.field.encoding import input_jets
from taichi_ndf.field.parameters import FieldParameters, resolve_dtype_device
from taichi_ndf.jets import CHANNELS

log = logging.getLogger(__name__)

INITIAL_DISPLACEMENT_RMS = 1e-3  # of output_scale: near the undeformed state
# Activations per channel and layer in one evaluation chunk (2048 samples at width 128, 3 MB
# buffers in float32). Measured on the 2-core CPU with first derivatives, per 10⁶ samples at
# width 128: 2^16 / 2^17 / 2^18 / 2^19 / 2^20 activations -> 1.72 / 1.61 / 1.57 / 1.64 / 1.80 s;
# the same optimum at width 512: smaller working sets stay in cache, smaller still costs calls.
EVALUATION_CHUNK_ACTIVATIONS = 2**18


def siren_parameters(config: FieldConfig, seed: int) -> list[torch.Tensor]:
    """SIREN initial weights and biases [W₁, b₁, ..., W_out, b_out] in float64 on the CPU.

    Drawn in float64 from a private generator, so the same seed gives the same field in any
    dtype (up to rounding) and does not disturb torch's global RNG.
    """
    generator = torch.Generator().manual_seed(seed)

    def uniform(shape, bound):
        return (torch.rand(shape, generator=generator, dtype=torch.float64) * 2 - 1) * bound

    params = []
    sizes = config.layer_sizes
    for i, (n_out, n_in) in enumerate(sizes):
        if i == len(sizes) - 1:
            weight = uniform((n_out, n_in), INITIAL_DISPLACEMENT_RMS * math.sqrt(6.0 / n_in))
            bias = torch.zeros(n_out, dtype=torch.float64)
        else:
            bound = 1.0 / n_in if i == 0 else math.sqrt(6.0 / n_in) / config.omega0
            weight = uniform((n_out, n_in), bound)
            bias = uniform((n_out,), 1.0 / math.sqrt(n_in))
        params += [weight, bias]
    return params


class _Tape:
    """Buffers of one jets call that backward reads; reused while N stays the same."""

    def __init__(self, config: FieldConfig, n: int, dtype: torch.dtype, device: torch.device):
        shape = (CHANNELS, n, config.width)
        layers = config.hidden_layers
        self.n = n
        self.pre = [torch.empty(shape, dtype=dtype, device=device) for _ in range(layers)]
        self.post = [torch.empty(shape, dtype=dtype, device=device) for _ in range(layers)]
        self.cos = [torch.empty(shape[1:], dtype=dtype, device=device) for _ in range(layers)]
        self.scratch = [torch.empty(shape, dtype=dtype, device=device) for _ in range(2)]
        self.ones = torch.ones(n, dtype=dtype, device=device)
        self.inputs: torch.Tensor | None = None
        self.weights: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.recorded = False


class NeuralField(FieldParameters):
    """SIREN displacement field u(ξ, c) with exact jets and weight gradients.

    parameters: [W₁, b₁, ..., W_out, b_out], weights shaped (out, in) like torch.nn.Linear,
        runtime dtype and device (``taichi_ndf.current()``) unless ``dtype``/``device`` given.
    gradients: tensors of the same shapes, overwritten in place by ``backward``.
    """

    def __init__(
        self,
        config: FieldConfig,
        *,
        seed: int = 0,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ):
        self.config = config
        self.dtype, self.device = resolve_dtype_device(dtype, device)
        self.parameters = [
            p.to(dtype=self.dtype, device=self.device) for p in siren_parameters(config, seed)
        ]
        self.gradients = [torch.zeros_like(p) for p in self.parameters]
        self.parameter_names = [
            f"layer{i}.{kind}"
            for i in range(len(config.layer_sizes))
            for kind in ("weight", "bias")
        ]
        self._tape: _Tape | None = None

    def _scales(self) -> list[float]:
        return [self.config.omega0] * self.config.hidden_layers + [self.config.output_scale]

    def _effective_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(scale·W, scale·b) per layer: ω₀ for sine layers, output_scale for the output."""
        w, b = self.parameters[0::2], self.parameters[1::2]
        return [(s * wi, s * bi) for s, wi, bi in zip(self._scales(), w, b, strict=True)]

    def _inputs(self, xi: torch.Tensor, conditioning: torch.Tensor | None):
        k = len(self.config.conditioning)
        if xi.ndim != 2 or xi.shape[1] != 2:
            raise ValueError(f"xi must have shape (N, 2), got {tuple(xi.shape)}")
        xi = xi.to(dtype=self.dtype, device=self.device)
        if k == 0:
            if conditioning is not None and conditioning.numel() > 0:
                raise ValueError("this field has no conditioning inputs, but got conditioning")
            return xi, None
        if conditioning is None or tuple(conditioning.shape) != (xi.shape[0], k):
            got = None if conditioning is None else tuple(conditioning.shape)
            raise ValueError(f"conditioning must have shape ({xi.shape[0]}, {k}), got {got}")
        return xi, conditioning.to(dtype=self.dtype, device=self.device)

    def jets(self, xi: torch.Tensor, conditioning: torch.Tensor | None = None) -> torch.Tensor:
        """Displacement jets w.r.t. the physical ξ, shape (N, 6, out_dim) [m, m, m, ...].

        xi: surface coordinates, shape (N, 2); conditioning: shape (N, k) if the field has k
        conditioning inputs. Keeps what ``backward`` needs from this (the last) call.
        """
        xi, conditioning = self._inputs(xi, conditioning)
        n = xi.shape[0]
        if self._tape is None or self._tape.n != n:
            log.debug("allocating jet buffers for %d samples", n)
            self._tape = None  # release the old buffers before allocating new ones
            self._tape = _Tape(self.config, n, self.dtype, self.device)
        tape = self._tape
        tape.recorded = False
        tape.inputs = input_jets(self.config, xi, conditioning, CHANNELS)
        tape.weights = self._effective_weights()
        h = tape.inputs
        for layer in range(self.config.hidden_layers):
            weight, bias = tape.weights[layer]
            pre = tape.pre[layer]
            torch.mm(h.view(CHANNELS * n, -1), weight.t(), out=pre.view(CHANNELS * n, -1))
            pre[0].add_(bias)
            sine_jets(pre, tape.post[layer], tape.cos[layer])
            h = tape.post[layer]
        weight, bias = tape.weights[-1]
        out = torch.mm(h.view(CHANNELS * n, -1), weight.t()).view(CHANNELS, n, -1)
        out[0].add_(bias)
        tape.recorded = True
        return out.transpose(0, 1).contiguous()

    def last_features(self) -> torch.Tensor:
        """Jets of the last hidden layer's activations from the last ``jets`` call, shape
        (6, N, width), channel-major: the raw output is linear in them, jets[:, c, k] =
        output_scale·(features[c] @ W_out[k] + b_out[k]·[c = value]). A view of the tape,
        overwritten by the next ``jets`` call."""
        tape = self._tape
        if tape is None or not tape.recorded:
            raise RuntimeError("last_features needs a preceding jets call")
        return tape.post[-1]

    def backward(self, grad_jets: torch.Tensor) -> None:
        """Gradient of a loss w.r.t. every parameter, from d loss / d jets (N, 6, out_dim).

        Overwrites ``self.gradients``; uses the buffers of the last ``jets`` call.
        """
        tape = self._tape
        if tape is None or not tape.recorded:
            raise RuntimeError("backward needs a preceding jets call")
        expected = (tape.n, CHANNELS, self.config.out_dim)
        if tuple(grad_jets.shape) != expected:
            raise ValueError(f"grad_jets must have shape {expected}, got {tuple(grad_jets.shape)}")
        n = tape.n
        grad = grad_jets.to(dtype=self.dtype, device=self.device).transpose(0, 1).contiguous()
        layer_inputs = [tape.inputs] + tape.post
        scratch = tape.scratch
        scales = self._scales()
        for layer in range(self.config.hidden_layers, -1, -1):
            scale = scales[layer]
            grad_w, grad_b = self.gradients[2 * layer], self.gradients[2 * layer + 1]
            flat = grad.view(CHANNELS * n, -1)
            inputs = layer_inputs[layer].view(CHANNELS * n, -1)
            if grad_w.shape[1] < grad_w.shape[0]:
                # Few inputs (first layer): BLAS is ~8x faster with the thin side as rows.
                grad_w.copy_(torch.mm(inputs.t(), flat).t())
            else:
                torch.mm(flat.t(), inputs, out=grad_w)
            grad_w.mul_(scale)
            # A GEMV with ones: torch.sum(dim=0) of the same (N, width) slice is ~100x slower.
            torch.mv(grad[0].t(), tape.ones, out=grad_b)
            grad_b.mul_(scale)
            if layer == 0:
                break
            below = scratch[1] if grad is scratch[0] else scratch[0]
            torch.mm(flat, tape.weights[layer][0], out=below.view(CHANNELS * n, -1))
            sine_jets_adjoint(tape.pre[layer - 1], tape.post[layer - 1], tape.cos[layer - 1], below)
            grad = below

    def evaluate(
        self,
        xi: torch.Tensor,
        conditioning: torch.Tensor | None = None,
        *,
        derivatives: bool = False,
        chunk: int | None = None,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Displacement [m], shape (N, out_dim), and with ``derivatives`` also (N, 2, out_dim).

        Processes ``chunk`` samples at a time (default: EVALUATION_CHUNK_ACTIVATIONS // width),
        so memory stays bounded for millions of points; keeps no state (``backward`` still
        refers to the last ``jets`` call).
        """
        if chunk is None:
            chunk = max(1, EVALUATION_CHUNK_ACTIVATIONS // self.config.width)
        if chunk < 1:
            raise ValueError(f"chunk must be a positive integer, got {chunk}")
        xi, conditioning = self._inputs(xi, conditioning)
        n = xi.shape[0]
        channels = 3 if derivatives else 1
        chunk = min(chunk, max(n, 1))
        width = self.config.width
        size = channels * chunk * width
        pre_buf = torch.empty(size, dtype=self.dtype, device=self.device)
        post_bufs = [torch.empty(size, dtype=self.dtype, device=self.device) for _ in range(2)]
        cos_buf = torch.empty(chunk * width, dtype=self.dtype, device=self.device)
        weights = self._effective_weights()
        result = torch.empty(channels, n, self.config.out_dim, dtype=self.dtype, device=self.device)
        for start in range(0, n, chunk):
            stop = min(start + chunk, n)
            m = stop - start
            cond = None if conditioning is None else conditioning[start:stop]
            h = input_jets(self.config, xi[start:stop], cond, channels)
            for layer in range(self.config.hidden_layers):
                weight, bias = weights[layer]
                pre = pre_buf[: channels * m * width].view(channels, m, width)
                post = post_bufs[layer % 2][: channels * m * width].view(channels, m, width)
                torch.mm(h.view(channels * m, -1), weight.t(), out=pre.view(channels * m, -1))
                pre[0].add_(bias)
                sine_jets(pre, post, cos_buf[: m * width].view(m, width))
                h = post
            weight, bias = weights[-1]
            out = torch.mm(h.view(channels * m, -1), weight.t())
            result[:, start:stop] = out.view(channels, m, -1)
            result[0, start:stop] += bias
        values = result[0]
        if not derivatives:
            return values
        return values, result[1:].transpose(0, 1).contiguous()
