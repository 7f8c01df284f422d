"""Saving and loading an exploration run's state (jaxquad.explore.checkpoint) on small pytrees: a round trip
keeps every value, type and random key; files of another run, of another layout or of no kind are refused."""

import dataclasses
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.explore import ExploreConfig
from jaxquad.explore import checkpoint as ck


class State(eqx.Module):
    x: jax.Array
    n: jax.Array
    key: jax.Array


class Out(eqx.Module):
    t: jax.Array
    pose: jax.Array


def _state(seed=0, rows=3):
    rng = np.random.default_rng(seed)
    return State(
        x=jnp.asarray(rng.normal(size=(rows, 4)), jnp.float32),
        n=jnp.asarray(rng.integers(0, 9, rows), jnp.int32),
        key=jax.random.split(jax.random.key(seed), rows),
    )


def _trace(ticks=5):
    return Out(t=np.arange(ticks, dtype=np.float32)[:, None].repeat(3, 1), pose=np.ones((ticks, 2, 3), np.float32))


def test_round_trip_keeps_values_types_and_random_keys(tmp_path):
    run = ck.identity(ExploreConfig(), np.zeros((2, 3)))
    states, trace = _state(1), _trace()
    ck.save(tmp_path / "run.npz", run, states, trace, chunks=4, chunk_s=[2.5, 3.0, 3.5, 3.5], compile_s=3.0)
    got = ck.load(tmp_path / "run.npz", run, _state(0), _trace(1))
    np.testing.assert_array_equal(got.states.x, states.x)
    np.testing.assert_array_equal(got.states.n, states.n)
    assert got.states.n.dtype == jnp.int32 and jax.dtypes.issubdtype(got.states.key.dtype, jax.dtypes.prng_key)
    # the keys draw what the saved ones draw
    np.testing.assert_array_equal(jax.random.uniform(got.states.key[2]), jax.random.uniform(states.key[2]))
    np.testing.assert_array_equal(got.trace.t, trace.t)
    assert (got.chunks, got.chunk_s, got.compile_s) == (4, [2.5, 3.0, 3.5, 3.5], 3.0)


def test_identity_tells_runs_apart_but_not_the_device_split():
    starts = np.array([[1.0, 2.0, 0.5]])
    base = ck.identity(ExploreConfig(), starts)
    assert ck.identity(dataclasses.replace(ExploreConfig(), devices=4), starts) == base
    assert ck.identity(dataclasses.replace(ExploreConfig(), seconds=61.0), starts) != base
    assert ck.identity(ExploreConfig(), starts + [[0.0, 0.01, 0.0]]) != base


def test_identity_holds_the_slam_parameters_by_value(tmp_path):
    """The same values from another file name are the same run; an edited file is another."""
    from jaxquad.slam import load_params

    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text("loop_search_maximum_distance: 2.5\n")
    b.write_text("loop_search_maximum_distance: 2.5\n")
    starts = np.zeros((1, 3))
    assert ck.identity(ExploreConfig(slam_params=str(a)), starts) == ck.identity(
        ExploreConfig(slam_params=str(b)), starts
    )
    b.write_text("loop_search_maximum_distance: 2.0\n")
    assert load_params(str(b))["loop_search_maximum_distance"] == 2.0
    assert ck.identity(ExploreConfig(slam_params=str(a)), starts) != ck.identity(
        ExploreConfig(slam_params=str(b)), starts
    )


def test_another_runs_file_is_refused(tmp_path):
    path = tmp_path / "run.npz"
    ck.save(path, ck.identity(ExploreConfig(), np.zeros((1, 3))), _state(), _trace(), 1, [0.0], 0.0)
    other = ck.identity(ExploreConfig(seed=1), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="other settings or starts"):
        ck.check(path, other)
    with pytest.raises(ValueError, match="other settings or starts"):
        ck.load(path, other, _state(), _trace())


@pytest.mark.parametrize(
    "like_states, like_trace",
    [
        (State(x=jnp.zeros((3, 5)), n=_state().n, key=_state().key), _trace()),  # a size changed
        (State(x=_state().x, n=_state().n.astype(jnp.float32), key=_state().key), _trace()),  # a type changed
        ((_state(), jnp.zeros(2)), _trace()),  # a field added
        (_state(), Out(t=np.zeros((1, 3), np.float32), pose=np.zeros((1, 3, 3), np.float32))),  # trace robots
    ],
)
def test_a_file_of_another_layout_is_refused(tmp_path, like_states, like_trace):
    run = ck.identity(ExploreConfig(), np.zeros((1, 3)))
    ck.save(tmp_path / "run.npz", run, _state(), _trace(), 1, [0.0], 0.0)
    with pytest.raises(ValueError, match="does not fit"):
        ck.load(tmp_path / "run.npz", run, like_states, like_trace)


def test_a_file_saved_on_another_device_count_says_so(tmp_path):
    """The robots are padded to a multiple of the devices: 3 robots saved, 4 slots here."""
    run = ck.identity(ExploreConfig(), np.zeros((1, 3)))
    ck.save(tmp_path / "run.npz", run, _state(rows=3), _trace(), 1, [0.0], 0.0)
    with pytest.raises(ck.CheckpointError, match="padded to 3 .* pads them to 4.*--devices"):
        ck.load(tmp_path / "run.npz", run, _state(rows=4), _trace())


def test_files_of_no_kind_are_refused_in_one_line(tmp_path):
    run = ck.identity(ExploreConfig(), np.zeros((1, 3)))
    (tmp_path / "text.npz").write_text("not a checkpoint\n")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with open(tmp_path / "cut.npz", "wb") as f:  # a checkpoint cut short
        f.write((ck.save(tmp_path / "whole.npz", run, _state(), _trace(), 1, [0.0], 0.0)).read_bytes()[:300])
    np.savez(tmp_path / "old.npz", meta=np.asarray(json.dumps({"format": "jaxquad-explore-checkpoint-1"})))
    cases = [("text", "unreadable"), ("other", "not an exploration checkpoint"), ("cut", "unreadable")]
    for name, match in [*cases, ("old", "another version of jaxquad")]:
        with pytest.raises(ck.CheckpointError, match=match) as e:
            ck.check(tmp_path / f"{name}.npz", run)
        assert "\n" not in str(e.value) and "unsafe" not in str(e.value)


def test_paused_says_where_and_how_far():
    e = ck.Paused("runs/go2.npz", 240.0, 600.0)
    assert "240.0 of 600.0" in str(e) and "runs/go2.npz" in str(e) and "\n" not in str(e)
