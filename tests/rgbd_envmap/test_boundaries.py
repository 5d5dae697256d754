"""Bad input at the public boundary: every case raises one of the project's typed errors naming the
argument, or gives a documented valid result (float16 input converted, read-only and Fortran-ordered
inputs read as they are) with no NaN. Outputs the library writes into must be writable: a read-only
``out`` is refused before any kernel sees it."""

import numpy as np
import pytest

from rgbd_envmap import colour, envmap, geometry, metrics, prt, sh
from rgbd_envmap.envmap import EnvironmentMap
from rgbd_envmap.errors import RgbdEnvmapError

rng = np.random.default_rng(0)


def ro(a):
    a = np.array(a)
    a.setflags(write=False)
    return a


H, W = 20, 40
em = EnvironmentMap(H, W)
pts = rng.normal(size=(50, 3))
cols = rng.random((50, 3)).astype(np.float32)

CASES = {
    "update config str": lambda: envmap.update(em, pts, cols, np.zeros(3), 100.0, config="x"),
    "update float16 pts": lambda: envmap.update(em, pts.astype(np.float16), cols, np.zeros(3), 100.0),
    "update complex pts": lambda: envmap.update(em, pts.astype(complex), cols, np.zeros(3), 100.0),
    "update fortran pts": lambda: envmap.update(em, np.asfortranarray(pts), cols, np.zeros(3), 100.0),
    "update em not map": lambda: envmap.update("map", pts, cols, np.zeros(3), 100.0),
    "update focal str": lambda: envmap.update(em, pts, cols, np.zeros(3), "f"),
    "update fill_only int": lambda: envmap.update(em, pts, cols, np.zeros(3), 100.0, fill_only=np.zeros(50,int)),
    "update seen wrong": lambda: envmap.update(em, pts, cols, np.zeros(3), 100.0, seen="x"),
    "update 1d pts": lambda: envmap.update(em, pts[:,0], cols, np.zeros(3), 100.0),
    "update nan device": lambda: envmap.update(em, pts, cols, np.array([np.nan,0,0]), 100.0),
    "update colours float16": lambda: envmap.update(em, pts, cols.astype(np.float16), np.zeros(3), 100.0),
    "update readonly pts": lambda: envmap.update(em, ro(pts), ro(cols), ro(np.zeros(3)), 100.0),
    "update huge pts count 0": lambda: envmap.update(em, np.empty((0,3)), np.empty((0,3)), np.zeros(3), 100.0),
    "translate str offset": lambda: envmap.translate(em, "x"),
    "translate out readonly": (lambda: (lambda o: (o.radiance_planes.setflags(write=False), envmap.translate(em, np.array([0.1,0,0]), out=o)))(EnvironmentMap(H,W))),
    "translate method int": lambda: envmap.translate(em, np.zeros(3), method=3),
    "translate not map": lambda: envmap.translate("x", np.zeros(3)),
    "translate threads str": lambda: envmap.translate(em, np.zeros(3), threads="2"),
    "translate gardner radius nan": lambda: envmap.translate(em, np.zeros(3), "gardner", radius_m=float('nan')),
    "translate max_splat_px -1": lambda: envmap.translate(em, np.array([0.1,0,0]), max_splat_px=-1),
    "translate max_rel_jump nan": lambda: envmap.translate(em, np.array([0.1,0,0]), max_rel_jump=float('nan')),
    "from_arrays nan radiance valid": lambda: EnvironmentMap.from_arrays(np.full((H,W,3),np.nan), np.ones((H,W)), np.ones((H,W),bool), np.zeros(3)),
    "from_arrays negative depth": lambda: EnvironmentMap.from_arrays(np.ones((H,W,3)), -np.ones((H,W)), np.ones((H,W),bool), np.zeros(3)),
    "from_arrays nan depth valid": lambda: EnvironmentMap.from_arrays(np.ones((H,W,3)), np.full((H,W),np.nan), np.ones((H,W),bool), np.zeros(3)),
    "from_arrays valid int": lambda: EnvironmentMap.from_arrays(np.ones((H,W,3)), np.ones((H,W)), np.ones((H,W),int), np.zeros(3)),
    "from_arrays float16": lambda: EnvironmentMap.from_arrays(np.ones((H,W,3),np.float16), np.ones((H,W),np.float16), np.ones((H,W),bool), np.zeros(3)),
    "map height float": lambda: EnvironmentMap(10.5, 20),
    "map huge": lambda: EnvironmentMap(100000, 200000),
    "collect_pairs float16": lambda: envmap.collect_pairs(em, pts.astype(np.float16), cols),
    "collect_pairs str": lambda: envmap.collect_pairs(em, "x", cols),
    "collect_pairs max diff nan": lambda: envmap.collect_pairs(em, pts, cols, max_depth_diff_m=float('nan')),
    "frame_points wrong intr": lambda: envmap.frame_points(np.ones((4,4)), np.ones((4,4),bool), "intr", None),
    "sh basis bands 0": lambda: sh.basis(np.array([[0,0,1.0]]), 0),
    "sh basis bands 1000": lambda: sh.basis(np.array([[0,0,1.0]]), 1000),

    "sh basis float16": lambda: sh.basis(np.array([[0,0,1.0]],np.float16), 3),
    "sh basis complex": lambda: sh.basis(np.array([[0,0,1.0]],complex), 3),
    "sh project bands str": lambda: sh.project_equirect(np.ones((H,W,3),np.float32), bands="5"),
    "sh project float16": lambda: sh.project_equirect(np.ones((H,W,3),np.float16)),
    "sh project nan": lambda: sh.project_equirect(np.full((H,W,3),np.nan,np.float32)),
    "sh project all invalid": lambda: sh.project_equirect(np.ones((H,W,3),np.float32), np.zeros((H,W),bool)),
    "sh project valid int": lambda: sh.project_equirect(np.ones((H,W,3),np.float32), np.ones((H,W),int)),
    "sh project bands 1000": lambda: sh.project_equirect(np.ones((H,W,3),np.float32), bands=1000),
    "sh irradiance wrong": lambda: sh.irradiance(np.ones((7,3)), np.array([0,0,1.0])),
    "sh irradiance nan": lambda: sh.irradiance(np.full((9,3),np.nan), np.array([0,0,1.0])),
    "ccm ridge str": lambda: colour.estimate_ccm(cols, cols, ridge="abc"),
    "ccm method bad": lambda: colour.estimate_ccm(cols, cols, method="bogus"),
    "ccm float16": lambda: colour.estimate_ccm(cols.astype(np.float16), cols),
    "ccm complex": lambda: colour.estimate_ccm(cols.astype(complex), cols),
    "ccm max_mse nan": lambda: colour.estimate_ccm(cols, cols, max_mse=float('nan')),
    "ccm min_pairs str": lambda: colour.estimate_ccm(cols, cols, min_pairs="3"),
    "decode_nv21 wrong": lambda: colour.decode_nv21(np.zeros((10,10),np.uint8), 10, 10),
    "decode_nv21 float": lambda: colour.decode_nv21(np.zeros((15,10)), 10, 10),
    "decode_nv21 h str": lambda: colour.decode_nv21(np.zeros((15,10),np.uint8), "10", 10),
    "srgb_to_linear str": lambda: colour.srgb_to_linear("x"),
    "srgb_to_linear float16": lambda: colour.srgb_to_linear(np.ones(3,np.float16)),
    "srgb complex": lambda: colour.srgb_to_linear(np.ones(3,complex)),
    "apply_ccm nan": lambda: colour.apply_ccm(cols, np.full((3,3),np.nan)),
    "invert singular": lambda: colour.invert_ccm(np.zeros((3,3))),
    "ws_psnr shapes": lambda: metrics.ws_psnr(np.ones((4,8)), np.ones((4,9))),
    "ws_psnr peak 0": lambda: metrics.ws_psnr(np.ones((4,8)), np.ones((4,8)), peak=0),
    "ws_psnr peak str": lambda: metrics.ws_psnr(np.ones((4,8)), np.ones((4,8)), peak="1"),
    "ws_psnr float16": lambda: metrics.ws_psnr(np.ones((4,8),np.float16), np.ones((4,8),np.float16)),
    "ws_psnr complex": lambda: metrics.ws_psnr(np.ones((4,8),complex), np.ones((4,8),complex)),
    "ws_psnr empty": lambda: metrics.ws_psnr(np.ones((0,0)), np.ones((0,0))),
    "corr valid none": lambda: metrics.sphere_correlation(np.ones((4,8,3)), np.ones((4,8,3))),
    "corr str": lambda: metrics.sphere_correlation("a","b"),
    "equirect dirs 0": lambda: geometry.equirect_directions(0, 0),
    "equirect dirs float": lambda: geometry.equirect_directions(2.5, 5),
    "equirect dirs huge": lambda: geometry.equirect_directions(10**6, 2*10**6),
    "d2e nan": lambda: geometry.directions_to_equirect(np.array([[np.nan,0,0]]), 4, 8),
    "d2e zero": lambda: geometry.directions_to_equirect(np.zeros((1,3)), 4, 8),
    "prt shade nan": lambda: prt.shade(np.ones((5,25),np.float32), np.full((25,3),np.nan), 0.5),
    "prt shade wrong": lambda: prt.shade(np.ones((5,25),np.float32), np.ones((9,3)), 0.5),
    "prt shade albedo str": lambda: prt.shade(np.ones((5,25),np.float32), np.ones((25,3)), "x"),
    "prt shade float16": lambda: prt.shade(np.ones((5,25),np.float16), np.ones((25,3)), 0.5),
    "prt shade out readonly": lambda: prt.shade(np.ones((5,25),np.float32), np.ones((25,3)), 0.5, out=ro(np.zeros((5,3),np.float32))),
    "prt shade out fortran": lambda: prt.shade(np.ones((5,25),np.float32), np.ones((25,3)), 0.5, out=np.asfortranarray(np.zeros((5,3),np.float32))),
}

TYPED = ['equirect dirs huge', 'update config str', 'update complex pts', 'update em not map', 'update focal str', 'update fill_only int', 'update seen wrong', 'update 1d pts', 'update nan device', 'translate str offset', 'translate out readonly', 'translate method int', 'translate not map', 'translate threads str', 'translate gardner radius nan', 'translate max_splat_px -1', 'translate max_rel_jump nan', 'from_arrays nan radiance valid', 'from_arrays negative depth', 'from_arrays nan depth valid', 'from_arrays valid int', 'map height float', 'map huge', 'collect_pairs str', 'collect_pairs max diff nan', 'frame_points wrong intr', 'sh basis bands 0', 'sh basis bands 1000', 'sh basis complex', 'sh project bands str', 'sh project nan', 'sh project valid int', 'sh project bands 1000', 'sh irradiance wrong', 'sh irradiance nan', 'ccm ridge str', 'ccm method bad', 'ccm complex', 'ccm max_mse nan', 'ccm min_pairs str', 'decode_nv21 wrong', 'decode_nv21 float', 'decode_nv21 h str', 'srgb_to_linear str', 'srgb complex', 'apply_ccm nan', 'invert singular', 'ws_psnr shapes', 'ws_psnr peak 0', 'ws_psnr peak str', 'ws_psnr complex', 'ws_psnr empty', 'corr str', 'equirect dirs 0', 'equirect dirs float', 'prt shade nan', 'prt shade albedo str', 'prt shade out readonly']
VALID = ['ccm float16', 'collect_pairs float16', 'from_arrays float16', 'prt shade float16', 'prt shade out fortran', 'prt shade wrong', 'sh basis float16', 'sh project all invalid', 'sh project float16', 'srgb_to_linear float16', 'update colours float16', 'update float16 pts', 'update fortran pts', 'update huge pts count 0', 'update readonly pts']


def _finite(result) -> bool:
    for x in result if isinstance(result, tuple) else (result,):
        if isinstance(x, np.ndarray) and x.dtype.kind in "fc" and not np.isfinite(x).all():
            return False
        if isinstance(x, float) and not np.isfinite(x):
            return False
    return True


@pytest.mark.parametrize("name", TYPED)
def test_bad_input_raises_a_typed_error(name):
    with pytest.raises(RgbdEnvmapError) as info:
        CASES[name]()
    # "argument: expected …, got …": the message starts with the argument's name.
    head, _, rest = str(info.value).partition(": ")
    assert head and " " not in head.strip("`'") or "×" in head, str(info.value)
    assert "expected" in rest or "unknown" in rest or "would take" in rest, str(info.value)


@pytest.mark.parametrize("name", VALID)
def test_accepted_input_gives_a_finite_result(name):
    assert _finite(CASES[name]())


def test_every_case_is_classified():
    assert set(TYPED) | set(VALID) <= set(CASES)
