"""The report's pictures show the physics: the colour is the actuation (not the gravity sag), the
side view keeps the coin between the DEA's far and near halves, the contact points drawn are
those inside the coin, the animation's x(t) marker moves once per GIF frame."""
import numpy as np
import pytest
from PIL import Image

from deapull.workflows.report import pictures, pictures_contact
from tests.workflows.test_report import _write_fields

COIN = pictures.CoinGeometry(centre_x_m=-0.037, radius_m=0.005, height_m=0.00225, edge_radius_m=0.0003)


@pytest.fixture
def synthetic(tmp_path):
    """The synthetic field file of test_report: a sag of 4 mm · s at rest, then 1 and 3 mm · t · s
    more along x and y (s = 0 at the clamp, 1 at the tip)."""
    return pictures.load_scene3d(_write_fields(tmp_path, np.linspace(0, 1, 5)))


def test_colour_is_the_actuation_from_rest_and_the_rest_frame_shows_the_sag(synthetic):
    """Broken once: ``actuation`` returned |u(t)| (the sag left in): frame 0 was not 0 and the
    frame-4 values carried the 4 mm sag."""
    s = synthetic
    tip = (s.points[:, 0] / -0.04) ** 2
    assert np.all(pictures.actuation(s, 0) == 0.0)
    rest = pictures.colouring(s, 0, sag_at_rest=False)
    assert np.all(rest.node_mm == 0.0) and rest.label == pictures.ACTUATION_LABEL
    t = s.fields.times[4]
    expected = np.hypot(1e-3 * t * tip, 3e-3 * t * tip) * 1e3           # the 4 mm sag is not in it
    assert np.allclose(pictures.colouring(s, 4).node_mm, expected)
    assert np.isclose(s.umax_mm, expected.max())
    sag = pictures.colouring(s, 0)                                        # the rest picture: the sag, labelled
    assert np.allclose(sag.node_mm, 4.0 * tip) and sag.label == pictures.SAG_LABEL
    assert np.isclose(sag.vmax_mm, 4.0 * tip.max())
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    coll = pictures.draw_side(ax, s, 0, colour=rest)                      # what is drawn is what is computed
    assert np.all(np.asarray(coll.get_array()) == 0.0)
    plt.close(fig)


def test_side_view_draws_the_far_half_before_the_coin_and_the_near_half_after():
    """Broken once: the groups swapped (near half first): the far half was drawn over the coin."""
    P = np.array([[0, 0, z] for z in (-3.0, -1.0, 2.0, 5.0)], dtype=float)
    polys = np.array([[0, 0], [1, 1], [2, 2], [3, 3]])
    behind, front = pictures.side_layers(P, polys)
    assert list(behind) == [3, 2] and list(front) == [1, 0]             # each far first, seen from -z


def test_contact_points_are_those_inside_the_coin_with_the_penalty_pressure():
    """Broken once: the depth as the flat top alone (top − y): the point beside the coin, below
    its top, was drawn as touching. Once: ``depth >= 0``: the point exactly on the top face was."""
    shift, k, top = -1e-3, 2.24e9, COIN.height_m
    cx = COIN.centre_x_m + shift
    x = np.array([[cx, top + 1e-6, 0.0],                  # above the top: free
                  [cx, top - 2e-6, 0.0],                  # in the top face, 2 µm deep
                  [cx + COIN.radius_m + 1e-3, top - 1e-3, 0.0],   # beside the coin, below its top: free
                  [cx + 0.003, top - 1e-6, 0.003],        # off the axis in z (rho = 4.2 mm), 1 µm deep
                  [cx + COIN.radius_m - 1e-4, top - 1e-4, 0.0]])   # on the rounded rim, inside the fillet
    touch = pictures_contact.touching(x, pictures_contact.coin_depth(x, COIN, shift), k)
    q = np.array([COIN.radius_m - 1e-4 - (COIN.radius_m - COIN.edge_radius_m), -1e-4 + COIN.edge_radius_m])
    rim_depth = COIN.edge_radius_m - np.hypot(*q)
    assert np.allclose(touch.points, x[[1, 3, 4]])
    assert np.allclose(touch.pressure, k * np.array([2e-6, 1e-6, rim_depth]), rtol=1e-6)
    dyadic = pictures.CoinGeometry(0.0, 2.0 ** -7, 2.0 ** -9, 2.0 ** -12)    # exact in binary: depth exactly 0
    on_top = np.array([[0.0, 2.0 ** -9, 0.0]])
    assert pictures_contact.coin_depth(on_top, dyadic, 0.0)[0] == 0.0
    assert pictures_contact.touching(on_top, pictures_contact.coin_depth(on_top, dyadic, 0.0), k).n == 0


def test_the_rule_is_basix():
    """The picture's twin of the solver's quadrature. Broken once: Gauss with
    degree // 2 points: 4 points at degree 8 where basix has 5."""
    basix = pytest.importorskip("basix")
    for rule, name in (("gauss", "default"), ("gauss_lobatto", "GLL")):
        for degree in (4, 6, 8):
            ref, _ = basix.make_quadrature(basix.quadrature.string_to_type(name), basix.CellType.interval, degree)
            assert np.allclose(pictures_contact.rule_points(degree, rule), np.sort(ref[:, 0])), (rule, degree)


def test_underside_is_sampled_at_the_quadrature_points_of_each_face(synthetic):
    """4 × 2 hexahedra under the DEA, 5 × 5 Gauss points each (degree 8), on the deformed surface.
    Broken once: the shape functions on nodes at [0, 1, 2] instead of [0, 0.5, 1]: the points stay
    on the surface but away from the Gauss points (the y check alone passed; the z check failed)."""
    s = synthetic
    x = pictures_contact.underside_samples(s, 2, 8, "gauss")
    assert x.shape == (4 * 2 * 25, 3)
    t = s.fields.times[2]
    X = x[:, 0].copy()
    for _ in range(20):                 # the reference x: x = X + u_x(X), u_x = -1 mm · t · s(X)
        X = x[:, 0] + 1e-3 * t * (X / -0.04) ** 2
    tip = (X / -0.04) ** 2
    y_expected = 0.00625 - 4e-3 * tip - 3e-3 * t * tip
    assert np.allclose(x[:, 1], y_expected, rtol=0, atol=1e-12)    # Q2 is exact on this quadratic field
    q = pictures_contact.rule_points(8, "gauss")                  # u_z = 0: z is each cell's Gauss points
    assert np.allclose(np.unique(x[:, 2].round(12)), np.concatenate([-0.01 + 0.01 * q, 0.01 * q]))


def test_animation_marker_moves_once_per_gif_frame(synthetic, tmp_path):
    """The x(t) panel's red marker sits at each frame's time: as many marker positions as GIF
    frames, moving right. Broken once: the marker drawn at the last frame's time in every frame."""
    gif = pictures.animation(synthetic, tmp_path / "a.gif", frames=4, progress=False)
    columns = []
    with Image.open(gif) as im:
        assert im.n_frames == len(pictures.animation_picks(synthetic, 4)) == 4
        for i in range(im.n_frames):
            im.seek(i)
            rgb = np.asarray(im.convert("RGB"), dtype=int)
            panel = rgb[:, int(0.72 * rgb.shape[1]):]
            red = (panel[..., 0] - panel[..., 1] > 100) & (panel[..., 0] - panel[..., 2] > 80)   # GIF palette
            assert red.sum() > 10, f"frame {i}: no marker"
            columns.append(np.nonzero(red)[1].mean())
    assert np.all(np.diff(columns) > 5), columns
