"""The shared transfer-function evaluator against closed forms."""

import numpy as np

from aeroid.frequency._transfer import state_space_response, transfer_at, transfer_response


def test_first_order_lag_with_delay_closed_form() -> None:
    w = np.array([0.0, 1.0, 2.0, 10.0])
    h = transfer_response([2.0], [1.0, 2.0], w, delay=0.1)
    expected = 2.0 / (1j * w + 2.0) * np.exp(-0.1j * w)
    np.testing.assert_allclose(h, expected, rtol=1e-14)
    assert np.isclose(abs(h[1]), np.sqrt(0.8))


def test_transfer_at_complex_s_matches_polynomials() -> None:
    s = np.array([1.0 + 2.0j, -0.5j])
    np.testing.assert_allclose(
        transfer_at([1.0, 3.0], [1.0, 0.4, 4.0], s), (s + 3.0) / (s**2 + 0.4 * s + 4.0)
    )


def test_state_space_matches_polynomial_form() -> None:
    # q/delta_e of a short period: x = [alpha, q]
    a = np.array([[-1.2, 1.0], [-5.0, -2.0]])
    b = np.array([[-0.1], [-8.0]])
    c = np.eye(2)
    d = np.zeros((2, 1))
    w = np.linspace(0.1, 20.0, 50)
    h = state_space_response(a, b, c, d, w)
    assert h.shape == (50, 2, 1)
    # q/de = (b2 s + (a21 b1 - a11 b2)) / (s^2 - tr s + det)
    num = [b[1, 0], a[1, 0] * b[0, 0] - a[0, 0] * b[1, 0]]
    den = [1.0, -np.trace(a), np.linalg.det(a)]
    np.testing.assert_allclose(h[:, 1, 0], transfer_response(num, den, w), rtol=1e-12)
