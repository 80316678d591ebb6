"""The registry of scene parameters (``jaximpact.parameters``) and the places that read it:
every place that takes a parameter's name takes exactly the registry's names and puts each in
the registry's place. Nothing here simulates."""

import argparse
import math

import equinox as eqx
import numpy as np
import pytest

import jaximpact as ji
from jaximpact._engine.sensitivity import IMPACT_INPUTS, output_jacobian
from jaximpact._io.scene_files import PRIOR_NAMES
from jaximpact._model.ranges import RANGES
from jaximpact.cli import scene_with_overrides
from jaximpact.parameters import (
    FITTABLE,
    PARAMETERS,
    TRANSFORMS,
    parameter_value,
    place,
    with_parameters,
)
from jaximpact.wall_law._capture import scene_with

TARGET = ji.Target(radius=21.7e-6, density=2500.0, omega0=3.0)


def scene_with_target():
    """Table 1 with a second sphere: a scene that holds every registered parameter."""
    return eqx.tree_at(lambda s: s.target, ji.table1_scene(), TARGET, is_leaf=lambda x: x is None)


def a_value(name: str) -> float:
    """A value inside the parameter's range that differs from the scenes' values here."""
    p = PARAMETERS[name]
    if p.default_prior is not None:
        return math.sqrt(p.default_prior[0] * p.default_prior[1])
    return {"radius2": 1e-3, "density2": 7000.0, "omega2": -5.0, "eta_n": 0.5}[name]


def test_every_parameter_has_a_place_in_the_scene_and_its_range_admits_the_default_value():
    scene = scene_with_target()
    for name, p in PARAMETERS.items():
        assert p.name == name
        holder = getattr(scene, p.section)
        assert p.key in type(holder).__dataclass_fields__, name
        # the default scene's value (Table 1's; the second sphere's for radius2, ...)
        value = np.asarray(parameter_value(scene, name))
        assert np.all(p.range.contains(value)), (name, value)
        assert (p.unit, p.lower, p.upper) == (RANGES[name].unit, RANGES[name].lo, RANGES[name].hi)
    # the default scene itself (no [target]) holds every parameter but the target's
    table1 = ji.table1_scene()
    for name in PARAMETERS:
        held = parameter_value(table1, name) is not None
        assert held == (PARAMETERS[name].section != "target"), name


def test_the_scene_parameters_of_the_simulator_are_registered():
    names = set(ji.scene_parameters(scene_with_target()))
    assert names <= set(PARAMETERS)
    for scene in (ji.table1_scene(), ji.load_scene("kharaz2001_mindlin")):
        for name, value in ji.scene_parameters(scene).items():
            assert parameter_value(scene, name) is value, name


def test_transform_round_trips_and_priors_lie_inside_the_range():
    assert FITTABLE == tuple(n for n, p in PARAMETERS.items() if p.transform is not None)
    for name in FITTABLE:
        p = PARAMETERS[name]
        assert p.transform in TRANSFORMS
        if p.default_prior is None:  # a unit that depends on the scene: the user gives one
            assert name == "eta_n"
            from fitting._bayesian.priors import default_prior
            from fitting._least_squares.objective import FitError

            with pytest.raises(FitError, match="eta_n has no default prior .* --prior eta_n="):
                default_prior(name)  # without the scene's damping model
        lo, hi = p.default_prior or (1e-6, 1.0)
        assert 0 < lo < hi
        assert p.range.contains(lo) and p.range.contains(hi), name
        if p.transform == "logit":  # bounded on both sides: the prior inside, ends excluded
            assert p.lower < lo and hi < p.upper
        for value in np.geomspace(lo, hi, 7):
            u = p.to_unbounded(value)
            assert math.isfinite(u)
            assert p.to_physical(u) == pytest.approx(value, rel=1e-12), (name, value)
        assert p.to_physical(p.to_unbounded(lo)) < p.to_physical(p.to_unbounded(hi))
    for name in set(PARAMETERS) - set(FITTABLE):
        with pytest.raises(ValueError, match="not fitted"):
            PARAMETERS[name].to_unbounded(1.0)


def test_the_fits_transforms_are_the_registrys():
    from fitting._least_squares.fit import _physical
    from fitting._least_squares.transforms import BOUNDS, to_physical, to_unbounded

    assert BOUNDS == {
        n: (p.lower, p.upper) for n, p in PARAMETERS.items() if p.transform == "logit"
    }
    names = list(FITTABLE)
    values = [a_value(n) for n in names]
    u = to_unbounded(names, values)
    assert list(u) == [PARAMETERS[n].to_unbounded(v) for n, v in zip(names, values, strict=True)]
    assert _physical(names, u) == {
        n: PARAMETERS[n].to_physical(x) for n, x in zip(names, u, strict=True)
    }
    np.testing.assert_allclose(np.asarray(to_physical(names, u)), values, rtol=1e-12)


def test_default_priors_are_the_registrys():
    from fitting._bayesian.priors import PRIOR_RANGES, default_prior

    assert PRIOR_RANGES == {n: PARAMETERS[n].default_prior for n in FITTABLE}
    for name in FITTABLE:
        if PARAMETERS[name].default_prior is None:  # eta_n: tested above
            continue
        prior = default_prior(name)
        assert (prior.kind, (prior.a, prior.b)) == ("loguniform", PARAMETERS[name].default_prior)


@pytest.mark.parametrize("put", [scene_with_overrides, scene_with, with_parameters])
def test_scene_writers_take_exactly_the_registrys_names(put):
    scene = scene_with_target()
    for name in PARAMETERS:
        moved = put(scene, {name: a_value(name)})
        assert float(parameter_value(moved, name)) == a_value(name), name
        for other in set(PARAMETERS) - {name}:  # nothing else moved
            assert parameter_value(moved, other) is parameter_value(scene, other)
    with pytest.raises(KeyError):
        put(scene, {"lambda_": 1.0})


def test_the_fit_takes_exactly_the_registrys_fittable_names():
    from fitting import FITTABLE as FIT_NAMES
    from fitting._least_squares.objective import (
        FitError,
        check_names,
        get_parameter,
        set_parameters,
    )

    assert tuple(FIT_NAMES) == FITTABLE
    assert FIT_NAMES == {n: place(n) for n in FITTABLE}
    assert check_names(FITTABLE) == FITTABLE
    scene = ji.table1_scene()
    for name in FITTABLE:
        assert get_parameter(scene, name) == float(parameter_value(scene, name))
        assert get_parameter(set_parameters(scene, {name: a_value(name)}), name) == a_value(name)
    for name in ("radius2", "speed", "lambda_"):
        with pytest.raises(FitError, match="unknown parameter"):
            check_names([name])
    with pytest.raises(KeyError):
        set_parameters(scene_with_target(), {"radius2": 1.0})
    # the scene file's [priors] takes the names a posterior samples
    assert PRIOR_NAMES == set(FITTABLE)


def test_sensitivities_refuse_a_name_outside_the_registry():
    scene = ji.table1_scene()
    with pytest.raises(ValueError, match="unknown input") as err:
        output_jacobian(scene, 1.0, 0.0, inputs=("f0", "lambda_"))
    for name in (*IMPACT_INPUTS, *PARAMETERS):
        assert name in str(err.value)


def test_capture_speed_refuses_a_scene_with_a_target():
    with pytest.raises(ji.SceneError, match=r"\[target\]"):
        ji.capture_speed(scene_with_target(), 0.0)


def test_fit_command_lists_the_registrys_names():
    from fitting.cli import add_fit_command

    fit = add_fit_command(argparse.ArgumentParser().add_subparsers())
    help_text = " ".join(fit.format_help().split())
    assert "from " + " ".join(FITTABLE) in help_text


def test_fit_data_column_the_scene_does_not_use_is_refused(tmp_path):
    """Fit data with a per-impact G_star column for a rigid-tangential scene: refused before
    any fitting, naming the file, the column and why (its values would change nothing)."""
    import pytest

    import jaximpact as ji
    from fitting import FitError, Objective

    data = tmp_path / "data.csv"
    data.write_text("speed,angle_deg,G_star,observable,value\n1.0,30,1e9,cor_n,0.8\n")
    with pytest.raises(FitError, match=r"data\.csv: column G_star: G_star is used only with"):
        Objective(ji.table1_scene(), data, ["C_H"])
