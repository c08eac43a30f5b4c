import numpy as np
import pytest
from synthetic_fields import noisy_fields, random_camera

torch = pytest.importorskip("torch")

from stereogeo_cli.geometry.fields import fields_and_jacobian_factors  # noqa: E402
from stereogeo_cli.refine import refine_camera  # noqa: E402
from stereogeo_cli.refine.torch_twin import fields_and_jacobian_factors as torch_factors  # noqa: E402
from stereogeo_cli.refine.torch_twin import refine_batch  # noqa: E402


def _batch(rng, count, size=(160, 120), **noise):
    cams, ups, lats, confs = [], [], [], []
    for _ in range(count):
        width, height, f, g, *_ = random_camera(rng, size)
        up, lat, c = noisy_fields(rng, width, height, f, g, **noise)
        cams.append((width, height, f, g))
        ups.append(up)
        lats.append(lat)
        confs.append(c)
    return cams, np.stack(ups), np.stack(lats), np.stack(confs)


def test_field_factors_equal_numpy():
    rng = np.random.default_rng(30)
    x, y = rng.uniform(0, 320, (2, 100)), rng.uniform(0, 240, (2, 100))
    gs = np.stack([random_camera(rng)[3] for _ in range(2)])
    fs = np.array([300.0, 150.0])
    out_t = torch_factors(
        torch.tensor(gs), torch.log(torch.tensor(fs)), torch.tensor(x), torch.tensor(y),
        torch.tensor([160.0, 160.0], dtype=torch.float64), torch.tensor([120.0, 120.0], dtype=torch.float64),
    )  # fmt: skip
    for b in range(2):
        out_n = fields_and_jacobian_factors(gs[b], fs[b], x[b], y[b], 160.0, 120.0)
        for a, t in zip(out_n, out_t, strict=True):
            np.testing.assert_allclose(t[b].numpy(), a, atol=1e-12)


@pytest.mark.parametrize("huber_scale", [None, 0.01])
def test_same_fields_same_steps_same_parameters(huber_scale):
    """NumPy refiner and torch twin agree to 1e-4 after the same number of steps from the same start."""
    rng = np.random.default_rng(31)
    cams, up, lat, conf = _batch(rng, 6)
    height, width = lat.shape[1:]
    g0 = np.tile([0.0, -1.0, 0.0], (len(cams), 1))
    f0 = np.full(len(cams), 0.7 * max(width, height))
    steps = 10
    xs, ys = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    g_t, f_t = refine_batch(
        torch.tensor(up.reshape(len(cams), -1, 2)), torch.tensor(lat.reshape(len(cams), -1)),
        torch.tensor(conf.reshape(len(cams), -1)), torch.tensor(conf.reshape(len(cams), -1)),
        torch.tensor(xs.ravel()), torch.tensor(ys.ravel()),
        torch.tensor([[width, height]] * len(cams), dtype=torch.float64), torch.tensor(g0), torch.tensor(f0),
        conf={"steps": steps, "huber_scale": huber_scale},
    )  # fmt: skip
    for b in range(len(cams)):
        fit = refine_camera(
            up[b], lat[b], conf[b], conf[b], gravity_init=g0[b], focal_init=f0[b],
            conf={"max_iterations": steps, "relative_tolerance": 0.0, "max_samples": None,
                  "huber_scale": huber_scale if huber_scale is not None else 1e6},
        )  # fmt: skip
        np.testing.assert_allclose(g_t[b].numpy(), fit.gravity_up, atol=1e-4)
        assert f_t[b].item() == pytest.approx(fit.focal_px, rel=1e-4)


def test_gradients_flow_to_fields_and_confidences():
    rng = np.random.default_rng(32)
    cams, up, lat, conf = _batch(rng, 3, size=(64, 48), outliers=0.0)
    n = len(cams)
    up_t = torch.tensor(up.reshape(n, -1, 2), dtype=torch.float32, requires_grad=True)
    lat_t = torch.tensor(lat.reshape(n, -1), dtype=torch.float32, requires_grad=True)
    conf_t = torch.tensor(conf.reshape(n, -1), dtype=torch.float32, requires_grad=True)
    xs, ys = np.meshgrid(np.arange(64.0), np.arange(48.0))
    g, f = refine_batch(
        up_t, lat_t, conf_t, conf_t, torch.tensor(xs.ravel(), dtype=torch.float32),
        torch.tensor(ys.ravel(), dtype=torch.float32), torch.tensor([[64.0, 48.0]] * n),
        torch.tensor([[0.0, -1.0, 0.0]] * n), torch.tensor([45.0] * n),
    )  # fmt: skip
    true_f = torch.tensor([c[2] for c in cams], dtype=torch.float32)
    loss = (torch.log(f) - torch.log(true_f)).abs().sum() + (
        g - torch.tensor(np.stack([c[3] for c in cams]))
    ).abs().sum()
    loss.backward()
    for t in (up_t, lat_t, conf_t):
        assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0
    errors = [abs(f[b].item() / cams[b][2] - 1) for b in range(n)]
    assert max(errors) < 0.05  # ten steps of the twin from a level start get close on noisy fields
