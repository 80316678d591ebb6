"""Impact and result tables (CSV): their columns, units, readers and atomic writers.

The public name of :mod:`jaximpact._io.tables`, where the code lives."""

from ._io.tables import *  # noqa: F403
from ._io.tables import __all__ as __all__
