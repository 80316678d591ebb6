"""``jaximpact fit``, ``jaximpact design`` and ``jaximpact export``: the commands ``fitting``
adds to ``jaximpact`` (entry points of the ``jaximpact.commands`` group, pyproject.toml).

The commands live in ``fitting._commands``: the options of ``fit`` (``fit_options``), the
command and the checks of its inputs (``fit_command``), its steps after the checks
(``fit_steps``), ``--compare`` (``compare``), ``design`` (``design_command``), ``export
lammps`` (``export_lammps``) and the reading of option words (``words``). This module keeps
the names other code imports from here.
"""

from __future__ import annotations

from ._commands.compare import _compared_models as _compared_models
from ._commands.compare import _law_names as _law_names
from ._commands.design_command import add_design_command as add_design_command
from ._commands.design_command import cmd_design as cmd_design
from ._commands.export_lammps import add_export_command as add_export_command
from ._commands.fit_command import add_fit_command as add_fit_command
from ._commands.fit_command import cmd_fit as cmd_fit
from ._commands.fit_options import EXIT_NOT_CONVERGED as EXIT_NOT_CONVERGED
from ._commands.fit_options import LOO_REFITS as LOO_REFITS
from ._commands.words import EMBEDDED_DATA as EMBEDDED_DATA
from ._commands.words import split_names as split_names

__all__ = ["add_design_command", "add_export_command", "add_fit_command", "cmd_design", "cmd_fit"]
