"""An independent numpy implementation of the captures' rendering convention.

Written from the formulas in ../shared/data/README.md, pixel by pixel in plain
numpy (float64), sharing no code with bayes_brdf.render.
"""
import numpy as np

PI = np.pi


def D(nh, alpha):
    a2 = alpha**2
    return a2 / (PI * (nh**2 * (a2 - 1) + 1) ** 2)


def G1(c, k):
    return c / (c * (1 - k) + k)


def G(nl, nv, alpha):
    k = alpha / 2
    return G1(nl, k) * G1(nv, k)


def F(vh, ks):
    return ks + (1 - ks) * 2.0 ** ((-5.55473 * vh - 6.98316) * vh)


def brdf(kd, r, ks, n, l, v, ks_factor=True, eps=1e-8):
    """kd, ks: (3,), r scalar, n/l/v unit (3,) -> f (3,)."""
    h = (l + v) / np.linalg.norm(l + v)
    nl, nv, nh, vh = (max(float(np.dot(a, b)), eps) for a, b in ((n, l), (n, v), (n, h), (v, h)))
    alpha = r * r
    diff = kd * (1 - ks) / PI if ks_factor else kd / PI
    spec = D(nh, alpha) * F(vh, ks) * G(nl, nv, alpha) / (4 * nl * nv)
    return diff + spec, nl


def texel_centers(res, size):
    x = ((np.arange(res) + 0.5) / res - 0.5) * size
    return x


def render_rectified(kd, r, ks, normal, size, cam, lights, ks_factor=True):
    """kd/ks/normal [H, W, 3], r [H, W]; lights: list of (pos, power(3,), falloff).

    Pixel (i, j) sees the texel centre (x_j, -x_i, 0) (row 0 at +y).
    """
    H, W = r.shape
    xs = texel_centers(W, size)
    ys = -texel_centers(H, size)
    out = np.zeros((H, W, 3))
    cam = np.asarray(cam, float)
    for i in range(H):
        for j in range(W):
            p = np.array([xs[j], ys[i], 0.0])
            v = (cam - p) / np.linalg.norm(cam - p)
            n = normal[i, j] / np.linalg.norm(normal[i, j])
            for pos, power, falloff in lights:
                lv = np.asarray(pos, float) - p
                d2 = float(lv @ lv)
                l = lv / np.sqrt(d2)
                f, nl = brdf(kd[i, j], r[i, j], ks[i, j], n, l, v, ks_factor)
                out[i, j] += f * nl * np.asarray(power, float) / (d2 if falloff else 1.0)
    return out
