"""Files of a wall law: NetCDF (xarray), Parquet (long table), posterior draws in."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._model.scene import SceneError
from ._capture import CaptureStatus
from ._law import KINK_MIN_DEG, KINKS, WallLaw
from ._refine import FILL_SHARE

__all__ = ["read_draws", "to_xarray", "write_netcdf", "write_parquet", "NETCDF", "PARQUET"]

NETCDF = "wall_law.nc"
PARQUET = "wall_law.parquet"
INSTALL_HINT = 'pip install "jaximpact[wall-law]" (xarray and h5netcdf)'

STATUS_TEXT = {0: "rebound", 1: "captured", -1: "not_simulated"}

#: Variables of the table: (dims: 3 = per lane, 4 = per cell), unit, description.
VARIABLES = {
    "capture_speed": (3, "m/s", "capture speed: below it the sphere sticks (0: no adhesion)"),
    "capture_status": (3, "1", "capture_speed's status (flag_meanings)"),
    "reference_speed": (3, "m/s", "the speed the speed_ratio axis is relative to"),
    "top_ratio": (
        3,
        "1",
        "largest valid speed_ratio of the row (the speed range, or below a second capture); "
        "the nodes above it repeat its results",
    ),
    "speed": (4, "m/s", "impact speed of the cell: speed_ratio * reference_speed"),
    "captured_above_top": (
        3,
        "1",
        "1 where the row sticks again above top_ratio, 0 where the speed range ends it",
    ),
    "status": (
        4,
        "1",
        "simulate's status of the cell: 0 rebound, 1 captured, -1 not simulated (a radius that "
        "sticks at every speed, or a speed above the speed range)",
    ),
    "cor_n": (4, "1", "normal restitution vn_out / v_n"),
    "cor_t": (4, "1", "tangential restitution vt_out / v_t (NaN at angle 0)"),
    "vt_ratio": (4, "1", "vt_out / speed (the tabulated tangential result)"),
    "spin_ratio": (4, "1", "omega_out radius / speed (the tabulated spin result)"),
    "vt_out": (4, "m/s", "tangential rebound speed"),
    "omega_out": (4, "rad/s", "rebound spin"),
    "rebound_angle_deg": (4, "deg", "rebound angle of the centre-of-mass velocity from the normal"),
}
UNCERTAINTY = {
    "capture_probability": ("1", "fraction of posterior draws captured at the cell's speed"),
    "cor_n_mean": ("1", "mean cor_n over the draws that rebound"),
    "cor_n_sd": ("1", "standard deviation of cor_n over the draws that rebound"),
    "cor_n_q05": ("1", "5 % quantile of cor_n over the draws that rebound"),
    "cor_n_q95": ("1", "95 % quantile of cor_n over the draws that rebound"),
}
KINK_U_ABOUT = (
    "kink-aligned angle coordinate: piecewise linear in the angle, j + (angle - b_j) / "
    "(b_(j+1) - b_j) between the breakpoints b = 0, the kink angles (clipped to at least "
    "kink_min_deg and made nondecreasing) and the top angle"
)
KINK_ANGLE_ABOUT = (
    "incidence angles of the kinks of the tangential results: below rolls_at_exit the sphere "
    "reaches rolling and still rolls when it leaves, below reaches_rolling (theta*) it "
    "reaches rolling; the top angle where the scan never passed the kink"
)
COORDS = {
    "radius": ("m", "sphere radius"),
    "angle_deg": ("deg", "incidence angle from the surface normal"),
    "omega0": ("rad/s", "initial spin, signed so that v_t = radius * omega0 is rolling"),
    "speed_ratio": ("1", "impact speed / reference_speed"),
}


def _xarray():
    try:
        import xarray as xr
    except ImportError:
        raise SceneError(f"writing or reading NetCDF needs xarray: {INSTALL_HINT}") from None
    return xr


def to_xarray(law: WallLaw, scene_name: str = ""):
    """The wall law as an ``xarray.Dataset`` (coordinates, units, the scene as attributes)."""
    xr = _xarray()
    coords, data = _coords_and_variables(law)
    attrs = {**_attributes(law, scene_name), **_report_attributes(law.radius_report)}
    attrs.update({f"scene.{k}": v for k, v in law.scene.items()})
    return xr.Dataset(data, coords=coords, attrs=attrs)


def _coords_and_variables(law: WallLaw) -> tuple[dict, dict]:
    """The dataset's coordinates and variables (``(dims, values, attrs)`` each), with units,
    descriptions and the status codes' flags."""
    dims3 = ("radius", "angle_deg", "omega0")
    # the aligned layout's rows and cells are on the aligned angle coordinate
    rows3 = ("radius", "kink_u", "omega0") if law.aligned else dims3
    dims4 = rows3 + ("speed_ratio",)
    coords = {
        k: (k, np.asarray(getattr(law, k), dtype=float), {"units": u, "long_name": d})
        for k, (u, d) in COORDS.items()
    }
    data = {}
    if law.aligned:
        coords["kink_u"] = ("kink_u", law.kink_u, {"units": "1", "long_name": KINK_U_ABOUT})
        coords["kink"] = ("kink", np.array(KINKS), {"long_name": "kinks of the aligned layout"})
        data["kink_angle_deg"] = (
            ("kink", "radius", "omega0", "speed_ratio"), law.kink_angles,
            {"units": "deg", "long_name": KINK_ANGLE_ABOUT},
        )  # fmt: skip
        data["cell_angle_deg"] = (
            dims4, np.asarray(law.cell_angle_deg),
            {"units": "deg", "long_name": "incidence angle of the cell"},
        )  # fmt: skip
    for name, (nd, unit, about) in VARIABLES.items():
        value = np.asarray(getattr(law, name))
        attrs = {"units": unit, "long_name": about}
        if name == "capture_status":
            attrs["flag_values"] = np.array(sorted(CaptureStatus.NAMES), dtype=np.int32)
            attrs["flag_meanings"] = " ".join(
                CaptureStatus.NAMES[k] for k in sorted(CaptureStatus.NAMES)
            )
            value = value.astype(np.int32)
        if name == "status":
            attrs["flag_values"] = np.array([-1, 0, 1], dtype=np.int32)
            attrs["flag_meanings"] = "not_simulated rebound captured"
            value = value.astype(np.int32)
        rows = rows3 if name in ("top_ratio", "captured_above_top") else dims3
        data[name] = (rows if nd == 3 else dims4, value, attrs)
    for name, (unit, about) in UNCERTAINTY.items():
        if name in law.uncertainty:
            data[name] = (dims4, law.uncertainty[name], {"units": unit, "long_name": about})
    return coords, data


def _attributes(law: WallLaw, scene_name: str) -> dict:
    """The dataset's description: its origin, speed axis, interpolation, layout and build."""
    from .. import __version__

    return {
        "title": "jaximpact wall law",
        "jaximpact_version": __version__,
        "scene_name": scene_name or "(given in Python)",
        "speed_axis": law.speed_axis,
        "speed_ratio_interpolation": (
            "linear in asinh(sqrt(speed_ratio - 1))"
            if law.speed_axis == "capture_ratio"
            else "linear in speed_ratio**0.2"
        ),
        "interpolation": (
            "kink_angle_deg multilinear in log(radius), omega0 and the speed coordinate; "
            "the results multilinear in log(radius), kink_u (of the query's angle at those "
            "kink angles), omega0 and the speed coordinate; the capture speed in "
            "log(radius), angle_deg and omega0"
            if law.aligned
            else "multilinear: log(radius), angle_deg, omega0 and the speed coordinate"
        ),
        "layout": "aligned" if law.aligned else "grid",
        **({"kink_min_deg": KINK_MIN_DEG} if law.aligned else {}),
        "build_seconds": float(law.seconds),
        "impacts_simulated": int(law.impacts),
        "posterior_draws": int(law.uncertainty.get("draws", 0)),
        "posterior_parameters": " ".join(law.uncertainty.get("parameters", [])),
    }


def _report_attributes(report: dict) -> dict:
    """The build report (``WallLaw.radius_report``) as attributes: the tolerances, the radius
    checks and what was left unresolved, the refined cells."""
    attrs = {}
    attrs["refine_tol"] = (
        "none (no refinement)"
        if report.get("refine_tol") is None
        else f"{report['refine_tol']:g} (angle and radius intervals split where linear "
        "interpolation of cor_n, cor_t or omega_out r / speed would miss by more)"
    )
    attrs["speed_tol"] = (
        "none (the speed nodes as given)"
        if report.get("speed_tol") is None
        else f"{report['speed_tol']:g} (speed intervals split where linear interpolation of "
        "a row's cor_n, cor_t or omega_out r / speed would miss by more)"
    )
    if "capture_tol" in report:
        attrs["radius_capture_tol"] = float(report["capture_tol"])
        attrs["radius_midpoints_checked"] = int(report["checked_midpoints"])
        attrs["radius_unresolved_intervals"] = _intervals(
            report["unresolved"], "capture speed off by"
        )
    if report.get("new_cells"):
        attrs["refined_cells"] = "; ".join(
            f"{stage}: {sim} of {total} new cells simulated, the others "
            f"interpolated (estimated miss below {FILL_SHARE:g} x refine_tol)"
            for stage, (sim, total) in report["new_cells"].items()
        )
    if "results_tol" in report:
        attrs["radius_results_tol"] = (
            f"{report['results_tol']:g} (radius intervals split where the table missed simulate "
            "by more at the interval's midpoint, on its aligned nodes)"
        )
        attrs["radius_results_checked"] = int(report["checked_radii"])
        attrs["radius_results_unresolved_intervals"] = _intervals(
            report["results_unresolved"], "missed by"
        )
    attrs["capture_speeds_not_converged"] = int(report.get("not_converged", 0))
    return attrs


def _intervals(bands, what: str) -> str:
    """Radius intervals ``(lo, hi, miss)`` as one attribute text ("none" when empty)."""
    return "; ".join(f"{lo:.6g}-{hi:.6g} m ({what} {miss:.3g})" for lo, hi, miss in bands) or "none"


def write_netcdf(path, law: WallLaw, scene_name: str = "") -> None:
    """``wall_law.nc`` (NetCDF-4 through h5netcdf), atomically."""
    from .._io.paths import atomic_output

    ds = to_xarray(law, scene_name)
    try:
        import h5netcdf  # noqa: F401
    except ImportError:
        raise SceneError(f"writing NetCDF needs h5netcdf: {INSTALL_HINT}") from None
    with atomic_output(path, "NetCDF file") as temp:
        ds.to_netcdf(str(temp), engine="h5netcdf")


def long_columns(law: WallLaw) -> dict:
    """One row per cell: the coordinates, then the results (numpy columns)."""
    second = law.kink_u if law.aligned else law.angle_deg
    grid = np.meshgrid(law.radius, second, law.omega0, law.speed_ratio, indexing="ij")
    cols = {k: g.ravel() for k, g in zip(COORDS, grid, strict=True)}
    cols["angle_deg"] = np.asarray(law.cell_angle_deg).ravel()
    if law.aligned:
        cols["kink_u"] = grid[1].ravel()
    cols["speed"] = law.speed.ravel()
    if law.aligned:  # the capture speed the table interpolates at the cell's angle
        with np.errstate(invalid="ignore", divide="ignore"):
            cols["capture_speed"] = cols["speed"] / cols["speed_ratio"]
    else:
        cols["capture_speed"] = np.broadcast_to(law.capture_speed[..., None], law.shape).ravel()
    cols["status"] = np.array([STATUS_TEXT.get(int(s), "failed") for s in law.status.ravel()])
    for name in ("cor_n", "cor_t", "vt_out", "omega_out", "rebound_angle_deg"):
        cols[name] = np.asarray(getattr(law, name), dtype=float).ravel()
    cols["vt_ratio"] = law.vt_ratio.ravel()
    cols["spin_ratio"] = law.spin_ratio.ravel()
    for name in UNCERTAINTY:
        if name in law.uncertainty:
            cols[name] = np.asarray(law.uncertainty[name], dtype=float).ravel()
    return cols


def write_parquet(path, law: WallLaw, scene_name: str = "") -> None:
    """``wall_law.parquet``: the long table, each column's unit as field metadata, the scene
    as file metadata; atomically."""
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    from .. import __version__
    from .._io.paths import atomic_output

    cols = long_columns(law)
    units = {k: u for k, (u, _) in COORDS.items()}
    units.update({k: u for k, (_, u, _) in VARIABLES.items()})
    units.update({k: u for k, (u, _) in UNCERTAINTY.items()})
    fields, arrays = [], []
    for name, values in cols.items():
        kind = pa.string() if values.dtype.kind in "OU" else pa.float64()
        unit = units.get(name, "")
        fields.append(pa.field(name, kind, metadata={"unit": unit} if unit else None))
        arrays.append(pa.array(values.tolist() if kind == pa.string() else values, type=kind))
    meta = {
        "jaximpact.version": __version__,
        "jaximpact.scene_name": scene_name or "(given in Python)",
        "jaximpact.speed_axis": law.speed_axis,
        "jaximpact.scene": json.dumps(law.scene),
    }
    table = pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=meta))
    with atomic_output(path, "Parquet file") as temp:
        pq.write_table(table, str(temp))


def read_draws(path) -> dict:
    """Posterior draws of scene parameters from an ArviZ NetCDF file (``jaximpact fit
    --posterior --draws FILE.nc``): ``{name: 1-D array}``, chains pooled; other variables
    (noise factors) are left out."""
    from .._engine.settings import PARAMETERS
    from .._io.paths import check_readable

    check_readable(path, "draws file")
    xr = _xarray()
    try:
        ds = xr.open_dataset(str(path), group="posterior", engine="h5netcdf")
    except Exception as err:  # not NetCDF, or no posterior group
        raise SceneError(f"{path}: not a draws file with a posterior group ({err})") from None
    with ds:
        names = [k for k in ds.data_vars if k in PARAMETERS or k in ("G_star", "w")]
        if not names:
            have = ", ".join(map(str, ds.data_vars))
            raise SceneError(f"{path}: no draws of a scene parameter (it has {have})")
        return {k: np.asarray(ds[k].values, dtype=float).ravel() for k in names}


def output_paths(directory) -> dict:
    d = Path(directory)
    return {"netcdf": d / NETCDF, "parquet": d / PARQUET}
