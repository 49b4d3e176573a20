"""One style per design in every figure of the suite, distinct for every catalogue design (issue 35: the sampling
study drew thm1 and lqr+rh_riccati both blue, the noise study light/dark pairs of one hue), and the states of the
catalogue plants named with their units."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.colors as mcolors  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bench.registry import DESIGNS, PLANTS  # noqa: E402
from bench.report import design_styles  # noqa: E402
from plants import Plant, PlantError  # noqa: E402


def _rgb(c) -> tuple:
    return tuple(round(v, 3) for v in mcolors.to_rgb(c))


def test_every_catalogue_design_has_its_own_colour_and_keeps_it():
    from bench.report import DESIGN_COLOURS

    ids = DESIGNS.ids()
    styles = design_styles(ids)
    colours = [_rgb(styles[d]["color"]) for d in ids]
    assert len(ids) >= 15
    if len(ids) <= len(DESIGN_COLOURS):
        assert len(set(colours)) == len(ids)
    else:  # more designs than colours: a colour comes back with another line style or marker
        assert len(set(colours)) == len(DESIGN_COLOURS)
        assert len({(c, styles[d]["linestyle"], styles[d]["marker"]) for c, d in zip(colours, ids)}) == len(ids)
    # the same design, drawn in another figure with other designs, in another order: the same style
    assert design_styles(["lqr+rh_riccati", "thm1"])["thm1"] == styles["thm1"]
    assert design_styles(["cor1"])["cor1"] == styles["cor1"]
    assert _rgb(styles["thm1"]["color"]) != _rgb(styles["lqr+rh_riccati"]["color"])
    assert _rgb(styles["cor1"]["color"]) != _rgb(styles["lqr+zhang_osl"]["color"])


def _lab(colour) -> np.ndarray:
    """CIELAB (D65) of a matplotlib colour, from the sRGB formulas."""
    rgb = np.array(mcolors.to_rgb(colour))
    rgb = np.where(rgb > 0.04045, ((rgb + 0.055) / 1.055) ** 2.4, rgb / 12.92)
    M = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = M @ rgb / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > 216 / 24389, np.cbrt(xyz), (24389 / 27 * xyz + 16) / 116)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_no_two_colours_of_the_palette_are_shades_of_one_hue():
    """tab20 pairs a dark and a light shade of each hue (the noise figure's trouble); every colour the palette adds
    to matplotlib's ten differs from each other one in hue (or is grey) and by a CIELAB distance of 25 or more,
    and an extra label (not registered) gets a look no registered design has."""
    import colorsys

    from bench.report import DESIGN_COLOURS

    tab10 = {f"C{i}" for i in range(10)}
    for a, b in ((a, b) for i, a in enumerate(DESIGN_COLOURS) for b in DESIGN_COLOURS[:i]):
        if a in tab10 and b in tab10:
            continue
        (h1, _, s1), (h2, _, s2) = (colorsys.rgb_to_hls(*mcolors.to_rgb(c)) for c in (a, b))
        assert np.linalg.norm(_lab(a) - _lab(b)) >= 25, (a, b)
        assert min(s1, s2) < 0.15 or min(abs(h1 - h2), 1 - abs(h1 - h2)) >= 0.03, (a, b)
    ids = DESIGNS.ids()
    styles = design_styles([*ids, "lqr+ekf (r = sigma^2)"])
    extra = styles["lqr+ekf (r = sigma^2)"]
    assert (extra["color"], extra["linestyle"], extra["marker"]) not in \
        {(s["color"], s["linestyle"], s["marker"]) for d, s in styles.items() if d in ids}


def test_noise_figure_tells_its_designs_apart():
    from bench.studies.noise import _draw

    designs = ["thm1", "cor1", "lqr+ekf", "lqr+lqe", "lqr+rh_riccati", "lqr+zhang_osl", "lqr+ekf (r = sigma^2)"]
    rows = [{"plant": "p", "design": d, "noise": s, "rms_e": (k + 1) * s, "final_x": s}
            for k, d in enumerate(designs) for s in (1e-3, 1e-2)]
    fig = _draw("p", rows)
    try:
        lines = [ln for ln in fig.axes[0].get_lines() if ln.get_label() in designs]
        assert len(lines) == len(designs)
        looks = {(_rgb(ln.get_color()), ln.get_linestyle(), ln.get_marker()) for ln in lines}
        assert len({lk[0] for lk in looks}) == len(designs)  # colours alone tell them apart
        assert len({lk[1:] for lk in looks}) >= 4  # and line style with marker, in greyscale
    finally:
        plt.close(fig)


def test_sampling_figure_uses_the_suite_colours():
    from bench.studies.sampling import _draw

    rows = [{"design": d, "h_max": 0.1, "settling_x_cont": 2.0} for d in ("thm1", "lqr+rh_riccati")]
    evals = [{"plant": "p", "design": d, "h": h, "settling_x_plant": 2.0 + h} for d in ("thm1", "lqr+rh_riccati")
             for h in (0.01, 0.1)]
    fig = _draw("p", rows, evals)
    try:
        got = {ln.get_label(): _rgb(ln.get_color()) for ln in fig.axes[0].get_lines() if ln.get_label() in
               ("thm1", "lqr+rh_riccati")}
        styles = design_styles(DESIGNS.ids())
        assert got == {d: _rgb(styles[d]["color"]) for d in got} and len(set(got.values())) == 2
    finally:
        plt.close(fig)


def test_catalogue_plants_name_their_states_with_units():
    for pid in PLANTS.ids():
        p = PLANTS.create(pid)
        if p.family.startswith("random"):  # synthetic: no physical states
            continue
        assert p.state_names is not None and len(p.state_names) == p.n, pid
        assert all(name.rstrip().endswith("]") for name in p.state_names), pid
    assert PLANTS.create("pendulum_v1").state_names == ("theta [rad]", "omega [rad/s]")


@pytest.mark.parametrize("names", [("a",), ("a", ""), "ab", 3, ("a", 2)])
def test_state_names_are_checked(names):
    with pytest.raises(PlantError, match="state_names: expected 2 non-empty strings"):
        Plant(id="p", A=-np.eye(2), B=np.ones((2, 1)), C=np.eye(1, 2), f=np.zeros_like, x0=np.ones(2),
              x_hat0=np.zeros(2), state_names=names)
