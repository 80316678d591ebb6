"""The columns of the impacts and results CSV files: names, order, which hold text, the
failure reasons and every column's SI unit (the formats: :mod:`.tables`)."""

#: Columns that describe the impact itself; ``speed`` and ``angle_deg`` are required.
IMPACT_COLUMNS = ("speed", "angle_deg", "omega0")


#: Scene parameters that an impacts CSV may override per row.
IMPACT_PARAMETER_COLUMNS = (
    "radius", "density", "K", "f0", "C_A", "C_H", "friction", "lambda", "G_star", "w", "p_y",
)  # fmt: skip


#: Columns a results CSV holds after the input columns, in this order.
RESULT_COLUMNS = (
    "status",
    "vn_out",
    "vt_out",
    "omega_out",
    "cor_n",
    "cor_t",
    "rebound_angle_deg",
    "contact_time",
    "roll_time",
    "max_overlap",
    "energy_in",
    "energy_out",
    "loss_hertz_damping",
    "loss_adhesion_damping",
    "loss_friction",
    "loss_rolling",
    "failure_reason",
)


#: Result columns that hold text; the others are numbers (NaN, an empty field, where they do
#: not apply). ``failure_reason`` is empty unless ``status`` is ``failed``, then one of
#: :data:`FAILURE_REASONS`.
TEXT_RESULT_COLUMNS = ("status", "failure_reason", "implausible")


#: Result columns a results CSV may add after :data:`RESULT_COLUMNS`: ``implausible``, the
#: plausibility flag of each impact (``jaximpact simulate`` writes it): empty, or a key of
#: :data:`IMPLAUSIBLE` (``large_overlap``: the maximum overlap is beyond the small-strain range
#: of Hertz contact; docs/input_ranges.md).
OPTIONAL_RESULT_COLUMNS = ("implausible",)


#: Why an impact failed (the ``failure_reason`` column; ``jaximpact.Status`` names them too).
FAILURE_REASONS = {
    "max_steps": "the solver's step limit was reached",
    "nonfinite": "the state became NaN or infinite",
    "solver_error": "the solver failed",
}


#: SI units of every impacts- and results-file column (CSV headers keep the bare names).
COLUMN_UNITS = {
    "speed": "m/s",
    "angle_deg": "deg",
    "omega0": "rad/s",
    "radius": "m",
    "density": "kg/m^3",
    "K": "N/m^2",
    "f0": "N/m",
    "C_A": "s/m",
    "C_H": "s/m",
    "friction": "1",
    "lambda": "N m",
    "G_star": "Pa",
    "w": "J/m^2",
    "p_y": "Pa",
    "status": "",
    "vn_out": "m/s",
    "vt_out": "m/s",
    "omega_out": "rad/s",
    "cor_n": "1",
    "cor_t": "1",
    "rebound_angle_deg": "deg",
    "contact_time": "s",
    "roll_time": "s",
    "max_overlap": "m",
    "energy_in": "J",
    "energy_out": "J",
    "loss_hertz_damping": "J",
    "loss_adhesion_damping": "J",
    "loss_friction": "J",
    "loss_rolling": "J",
    "failure_reason": "",
    "implausible": "",
}


#: The statuses the conventions define for a simulated impact.
RESULT_STATUSES = ("rebound", "captured", "failed")
