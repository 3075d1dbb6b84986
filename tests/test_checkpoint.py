"""Checkpoints: exact round trip, weights_only loading, mismatch errors, atomic writes."""

import pytest
import torch

from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.minimise.checkpoint import load_checkpoint, save_checkpoint
from taichi_ndf.problem.optim import Adam, AdamConfig

F64 = torch.float64
CONFIG = FieldConfig(width=12, hidden_layers=2, periodic=(True, False), conditioning=((0, 2),))


def trained(seed=0, steps=3):
    """A field and optimiser after a few steps on an arbitrary loss, plus its samples."""
    field = NeuralField(CONFIG, seed=seed)
    adam = Adam(field.parameters, field.gradients, config=AdamConfig(lr=1e-2))
    g = torch.Generator().manual_seed(seed)
    xi, cond = torch.rand(40, 2, generator=g, dtype=F64), torch.rand(40, 1, generator=g, dtype=F64)
    for _ in range(steps):
        field.backward(field.jets(xi, cond))
        adam.step()
    return field, adam, xi, cond


def test_round_trip_reproduces_outputs_and_optimiser_exactly(tmp_path):
    field, adam, xi, cond = trained()
    path = save_checkpoint(
        tmp_path / "run" / "ckpt.pt", field, adam, extra={"iteration": 3, "scene": "napkin"}
    )

    other = NeuralField(CONFIG, seed=1)
    other_adam = Adam(other.parameters, other.gradients, config=AdamConfig(lr=1e-2))
    loaded = load_checkpoint(path, other, optimiser=other_adam)
    assert loaded.field is other
    assert loaded.extra == {"iteration": 3, "scene": "napkin"}
    assert torch.equal(other.jets(xi, cond), field.jets(xi, cond))
    for a, b in ((field, adam), (other, other_adam)):
        a.backward(a.jets(xi, cond))
        b.step()
    assert torch.equal(other.get_flat(), field.get_flat())


def test_loading_without_a_field_builds_one(tmp_path):
    field, _, xi, cond = trained()
    path = save_checkpoint(tmp_path / "ckpt.pt", field)
    loaded = load_checkpoint(path)
    assert loaded.field.config == CONFIG
    assert loaded.optimiser_state is None
    assert torch.equal(loaded.field.jets(xi, cond), field.jets(xi, cond))


def test_file_is_loadable_with_weights_only(tmp_path):
    field, adam, _, _ = trained()
    path = save_checkpoint(tmp_path / "ckpt.pt", field, adam, extra={"losses": [1.0, 0.5]})
    payload = torch.load(path, weights_only=True)
    assert payload["format_version"] == 1
    assert payload["architecture"]["width"] == 12
    assert payload["optimiser"]["step"] == 3


def test_mismatched_architecture_names_the_difference(tmp_path):
    field, _, _, _ = trained()
    path = save_checkpoint(tmp_path / "ckpt.pt", field)
    narrow = NeuralField(
        FieldConfig(width=8, hidden_layers=2, periodic=(True, False), conditioning=((0, 2),))
    )
    with pytest.raises(ValueError, match="width: checkpoint 12, field 8"):
        load_checkpoint(path, narrow)
    flat = NeuralField(FieldConfig(width=12, hidden_layers=2, conditioning=((0, 2),)))
    with pytest.raises(
        ValueError, match=r"periodic: checkpoint \(True, False\), field \(False, False\)"
    ):
        load_checkpoint(path, flat)
    with pytest.raises(ValueError, match="holds no optimiser state"):
        load_checkpoint(path, optimiser=Adam(field.parameters, field.gradients))


def test_rejects_files_that_are_not_checkpoints(tmp_path):
    torch.save({"weights": torch.zeros(3)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a taichi_ndf checkpoint"):
        load_checkpoint(tmp_path / "other.pt")


def test_failed_save_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    field, _, xi, cond = trained()
    path = save_checkpoint(tmp_path / "ckpt.pt", field)
    before = path.read_bytes()

    with pytest.raises(TypeError, match=r"extra\['scene'\] is a object"):
        save_checkpoint(path, field, extra={"scene": object()})

    def interrupted(obj, stream):
        stream.write(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, NeuralField(CONFIG, seed=9))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]


def test_state_round_trip_restores_weights_moments_generator_and_counters(tmp_path):
    from taichi_ndf.minimise.state import MonitorRecord, State

    field, adam, _, _ = trained()
    generator = torch.Generator().manual_seed(5)
    torch.rand(7, generator=generator)  # a generator part-way along its stream
    record = MonitorRecord(iteration=3, load_factor=0.5, energy=-1.25, grad_norm=0.1,
                           learning_rate=1e-2, probes={"tip": [0.0, 0.5, -1.0]}, wall_time=2.0)
    state = State(field, adam, generator, iteration=3, load_step=1, newton_steps=4,
                  history=[record])
    state.save(tmp_path / "state.pt", {"scene": "napkin"})

    other_field = NeuralField(CONFIG, seed=1)
    other = State.initial(other_field, AdamConfig(lr=1e-2), seed=0)
    extra = other.restore(tmp_path / "state.pt")
    assert extra["scene"] == "napkin"
    assert (other.iteration, other.load_step, other.newton_steps) == (3, 1, 4)
    assert other.history == [record]
    assert torch.equal(other_field.get_flat(), field.get_flat())
    assert other.optimiser.state_dict()["step"] == adam.state_dict()["step"]
    for a, b in zip(other.optimiser.exp_avg_sq, adam.exp_avg_sq, strict=True):
        assert torch.equal(a, b)
    assert torch.equal(torch.rand(5, generator=other.generator), torch.rand(5, generator=generator))


def test_restoring_a_missing_state_names_the_path(tmp_path):
    from taichi_ndf.minimise.state import State

    field, _, _, _ = trained()
    state = State.initial(field, AdamConfig(), seed=0)
    with pytest.raises(FileNotFoundError, match="no checkpoint to resume from"):
        state.restore(tmp_path / "missing.pt")
