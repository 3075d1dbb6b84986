import torch

from taichi_ndf import jets


def _poly_jet(coeffs, xi):
    """Jet of f = c0 + c1 x + c2 y + c3 x² + c4 xy + c5 y² + c6 x²y + c7 sin(x+2y)."""
    x, y = xi[:, 0], xi[:, 1]
    c = coeffs
    s, co = torch.sin(x + 2 * y), torch.cos(x + 2 * y)
    f = (c[0] + c[1] * x + c[2] * y + c[3] * x**2 + c[4] * x * y + c[5] * y**2
         + c[6] * x**2 * y + c[7] * s)
    fx = c[1] + 2 * c[3] * x + c[4] * y + 2 * c[6] * x * y + c[7] * co
    fy = c[2] + c[4] * x + 2 * c[5] * y + c[6] * x**2 + 2 * c[7] * co
    fxx = 2 * c[3] + 2 * c[6] * y - c[7] * s
    fxy = c[4] + 2 * c[6] * x - 2 * c[7] * s
    fyy = 2 * c[5] - 4 * c[7] * s
    return torch.stack((f, fx, fy, fxx, fxy, fyy), dim=1)[..., None]


def test_product_rule_matches_autograd():
    gen = torch.Generator().manual_seed(0)
    xi = torch.rand(7, 2, dtype=torch.float64, generator=gen)
    ca = torch.randn(8, dtype=torch.float64, generator=gen)
    cb = torch.randn(8, dtype=torch.float64, generator=gen)
    prod = jets.product(_poly_jet(ca, xi), _poly_jet(cb, xi))[:, :, 0]

    def f(p):
        return (_poly_jet(ca, p[None]) * _poly_jet(cb, p[None]))[0, 0, 0]

    for i in range(xi.shape[0]):
        g = torch.autograd.functional.jacobian(f, xi[i])
        h = torch.autograd.functional.hessian(f, xi[i])
        expected = torch.stack((f(xi[i]), g[0], g[1], h[0, 0], h[0, 1], h[1, 1]))
        torch.testing.assert_close(prod[i], expected, rtol=1e-12, atol=1e-12)


def test_product_adjoint_is_transpose():
    gen = torch.Generator().manual_seed(1)
    a = torch.randn(5, 6, 3, dtype=torch.float64, generator=gen)
    b = torch.randn(5, 6, 3, dtype=torch.float64, generator=gen, requires_grad=True)
    g = torch.randn(5, 6, 3, dtype=torch.float64, generator=gen)
    (jets.product(a, b) * g).sum().backward()
    torch.testing.assert_close(jets.product_adjoint(a, g), b.grad, rtol=1e-12, atol=1e-12)
