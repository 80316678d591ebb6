"""The SMC program compiled ahead, in a background thread, while the least-squares fit runs
(``prepare_posterior``; ``fit --posterior`` and ``sample_posterior`` without a fit do it): the
sampler then uses that very program, and its draws are those of a run without it."""

import numpy as np
import pytest

import jaximpact as ji
from fitting._bayesian import posterior, programs

SIGMA = 0.003


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    truth = ji.table1_scene().replace(contact=dict(C_A=0.75, C_H=0.25, f0=300.0))
    speed = np.geomspace(0.3, 5.0, 6)
    clean = np.asarray(ji.simulate(truth, speed, 0.0, 0.0).cor_n)
    y = clean + SIGMA * np.random.default_rng(3).standard_normal(speed.size)
    path = tmp_path_factory.mktemp("prepare") / "data.csv"
    rows = [f"{float(s)!r},0.0,cor_n,{float(v)!r},{SIGMA}" for s, v in zip(speed, y, strict=True)]
    path.write_text("speed,angle_deg,observable,value,sigma\n" + "\n".join(rows) + "\n")
    return truth, path


def _run(truth, path, **kw):
    return posterior.sample_posterior(
        truth, path, ["C_A", "f0"], chains=2, draws=200, starts=1, progress=False, **kw
    )


def test_prepared_program_is_the_one_sampled_with_and_changes_no_draw(data):
    truth, path = data
    programs._PROGRAMS.clear()
    assert posterior.prepare_posterior(truth, path, ["C_A", "f0"], draws=200)
    (key,) = programs._PROGRAMS
    assert isinstance(programs._PROGRAMS[key], programs.Future)  # compiling in the background
    fit = posterior.fit(truth, path, ["C_A", "f0"], starts=1, progress=False)
    prepared = _run(truth, path, fit_result=fit)
    # the sampler found the prepared program: no second compile, the future resolved in place
    assert list(programs._PROGRAMS) == [key]
    assert not isinstance(programs._PROGRAMS[key], programs.Future)
    programs._PROGRAMS.clear()
    plain = _run(truth, path, fit_result=fit)
    assert np.array_equal(prepared.draws, plain.draws)
    assert np.array_equal(prepared.log_density, plain.log_density)


def test_sample_posterior_prepares_while_it_fits(data):
    truth, path = data
    programs._PROGRAMS.clear()
    result = _run(truth, path)
    assert len(programs._PROGRAMS) == 1 and result.evaluations > 0
    assert not isinstance(next(iter(programs._PROGRAMS.values())), programs.Future)


@pytest.mark.parametrize(
    "options",
    [
        dict(likelihood="cauchy"),
        dict(moves="hmc"),
        dict(noise="integrated", likelihood="student-t"),
    ],
)
def test_options_the_sampler_refuses_start_nothing(data, options):
    """The sampler's own call refuses them, with its message; preparing is silent."""
    truth, path = data
    programs._PROGRAMS.clear()
    assert not posterior.prepare_posterior(truth, path, ["C_A", "f0"], **options)
    assert not programs._PROGRAMS
    assert not posterior.prepare_posterior(truth, path.with_name("missing.csv"), ["C_A", "f0"])
