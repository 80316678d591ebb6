"""Capture speed and wall laws for CFD codes.

- :func:`capture_speed`: the speed below which a sphere sticks, per angle and spin,
  differentiable with respect to every scene parameter (implicit-function theorem).
- :func:`wall_law`: rebound tables over radius, angle, spin and speed relative to the capture
  speed (:class:`WallLaw`), written by :func:`write_wall_law` as NetCDF, Parquet, a C99 header,
  an OpenFOAM patch interaction model and a Fluent UDF (``jaximpact wall-law``).
"""

from ._capture import CaptureSpeed as CaptureSpeed
from ._capture import CaptureStatus as CaptureStatus
from ._capture import adhesion_speed as adhesion_speed
from ._capture import capture_speed as capture_speed
from ._check import compare_with_simulate as compare_with_simulate
from ._check import random_points as random_points
from ._codegen import c_header as c_header
from ._codegen import write_code as write_code
from ._io import read_draws as read_draws
from ._io import to_xarray as to_xarray
from ._io import write_netcdf as write_netcdf
from ._io import write_parquet as write_parquet
from ._law import WallLaw as WallLaw
from ._law import WallLawError as WallLawError
from ._table import wall_law as wall_law


def write_wall_law(law: WallLaw, directory, scene_name: str = "") -> None:
    """Write ``law`` into ``directory`` as the command does: ``wall_law.nc``,
    ``wall_law.parquet``, ``jaximpact_wall_law.h``, ``openfoam/`` and ``fluent/``."""
    from pathlib import Path

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    write_netcdf(directory / "wall_law.nc", law, scene_name)
    write_parquet(directory / "wall_law.parquet", law, scene_name)
    write_code(law, directory, scene_name)
