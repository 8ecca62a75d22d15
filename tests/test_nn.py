"""The neural-network layer: seeded training with checkpoints that resume, ONNX export
checked against torch, model metadata, sessions."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from services.lib.nn.device import choose_device
from services.lib.nn.onnx_io import export_onnx, read_model, session
from services.lib.nn.regression import TrainConfig, train


def _data(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(256, 4)).astype(np.float32)
    y = (x @ np.array([[1.0, -2.0], [0.5, 0.0], [0.0, 1.5], [2.0, 1.0]], np.float32)) + 0.3
    return x, y.astype(np.float32)


def _model() -> torch.nn.Module:
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(4, 16), torch.nn.ReLU(), torch.nn.Linear(16, 2))


def test_training_learns_and_is_seeded() -> None:
    x, y = _data()
    config = TrainConfig(epochs=8, batch=32, learning_rate=0.05, seed=3, device="cpu", threads=1)
    first, second = _model(), _model()
    result = train(first, x, y, config)
    train(second, x, y, config)
    losses = [h["val"] for h in result.history]
    assert losses[-1] < 0.2 * losses[0] and result.best_val_loss == min(losses)
    for a, b in zip(first.parameters(), second.parameters(), strict=True):
        assert torch.equal(a, b)  # the same seed gives the same weights


def test_training_resumes_from_its_checkpoint(tmp_path) -> None:
    x, y = _data()
    config = TrainConfig(epochs=2, batch=64, seed=1, device="cpu", threads=1)
    model = _model()
    earlier = train(model, x, y, config, checkpoint_dir=tmp_path)
    messages = []
    later = train(
        model,
        x,
        y,
        TrainConfig(epochs=3, batch=64, seed=1, device="cpu", threads=1),
        checkpoint_dir=tmp_path,
        progress=lambda fraction, message: messages.append(message),
    )
    assert messages[0] == "resuming after epoch 2" and len(later.history) == 3
    assert later.seconds > earlier.seconds  # the time of both runs
    with pytest.raises(ValueError, match="need ≥ 2 pairs"):
        train(_model(), x[:1], y[:1], config)


def test_onnx_export_matches_torch_and_carries_metadata(tmp_path) -> None:
    model = _model().eval()
    x, _ = _data()
    path = tmp_path / "m.onnx"
    difference = export_onnx(model, x[:3], path, {"architecture": "toy", "metrics": {"mse": 1}})
    assert difference < 1e-5
    assert read_model(path).metadata == {"architecture": "toy", "metrics": {"mse": 1}}
    out = session(path, threads=1).run(None, {"input": x[:10]})[0]
    assert np.allclose(out, model(torch.from_numpy(x[:10])).detach().numpy(), atol=1e-5)
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="not an ONNX model"):
        read_model(tmp_path / "junk.onnx")


def test_a_model_file_fills_its_network_with_batch_norms_folded(tmp_path) -> None:
    """A network with trained batch norms exported, then read back into the same network
    with them folded: the same answers, exported again the same file's answers (how a
    shipped model is fine-tuned)."""
    from torch import nn

    from services.lib.nn.onnx_io import fold_batch_norms, load_onnx_weights

    def network() -> nn.Module:
        return nn.Sequential(
            nn.Sequential(nn.Conv2d(3, 8, 3, padding=1, bias=False), nn.BatchNorm2d(8), nn.ReLU()),
            nn.Sequential(nn.ConvTranspose2d(8, 4, 2, stride=2, bias=False), nn.BatchNorm2d(4)),
            nn.Conv2d(4, 2, 1),
        )

    torch.manual_seed(0)
    trained = network()
    for norm in (m for m in trained.modules() if isinstance(m, nn.BatchNorm2d)):
        norm.running_mean.uniform_(-1, 1)
        norm.running_var.uniform_(0.5, 2)
        norm.weight.data.uniform_(0.5, 1.5)
        norm.bias.data.uniform_(-0.5, 0.5)
    trained.eval()
    x = np.random.default_rng(0).random((2, 3, 16, 16), dtype=np.float32)
    export_onnx(trained, x, tmp_path / "a.onnx", {}, free_axes=(0, 2, 3))
    folded = fold_batch_norms(network())
    load_onnx_weights(folded, tmp_path / "a.onnx")
    folded.eval()
    with torch.no_grad():
        expected = trained(torch.from_numpy(x)).numpy()
        assert np.abs(folded(torch.from_numpy(x)).numpy() - expected).max() < 1e-5
    export_onnx(folded, x, tmp_path / "b.onnx", {}, free_axes=(0, 2, 3))
    again = fold_batch_norms(network())
    load_onnx_weights(again, tmp_path / "b.onnx")
    with torch.no_grad():
        assert np.abs(again.eval()(torch.from_numpy(x)).numpy() - expected).max() < 1e-5
    with pytest.raises(ValueError, match="another network"):
        load_onnx_weights(fold_batch_norms(nn.Sequential(nn.Conv2d(3, 5, 3))), tmp_path / "a.onnx")


def test_device_choice() -> None:
    assert choose_device("cpu").type == "cpu"
    assert choose_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ValueError, match="known devices"):
        choose_device("tpu")


def test_a_diverging_run_says_so() -> None:
    x, y = _data()
    config = TrainConfig(epochs=2, batch=32, learning_rate=1e6, clip_norm=1e12, device="cpu")
    with pytest.raises(ValueError, match="training diverged in epoch 1"):
        train(_model(), x, y * 1e6, config)


def test_targets_in_different_units_are_learned_alike_and_answered_in_their_units() -> None:
    x, y = _data()
    y = y * np.array([1000.0, 0.001], np.float32)  # one column in µm, the other in m
    config = TrainConfig(epochs=20, batch=32, learning_rate=0.05, seed=2, device="cpu", threads=1)
    result = train(_model(), x, y, config)
    relative = np.array(result.val_rmse) / y.std(axis=0)
    assert relative.max() < 0.15 and relative.max() < 2 * relative.min(), relative  # alike
    with torch.no_grad():
        answered = result.model(torch.from_numpy(x)).numpy()
    assert np.all(np.sqrt(np.mean((answered - y) ** 2, axis=0)) / y.std(axis=0) < 0.15)
    assert result.split == {"train": 204, "val": 26, "test": 26}  # the thesis's 80/10/10
    assert result.test_rmse is not None and len(result.test_rmse) == 2


def test_a_checkpoint_of_other_data_or_settings_is_not_resumed(tmp_path) -> None:
    x, y = _data()
    config = TrainConfig(epochs=1, batch=64, seed=1, device="cpu", threads=1)
    train(_model(), x, y, config, checkpoint_dir=tmp_path)
    for data, settings in [(y + 1.0, config), (y, replace(config, learning_rate=0.5))]:
        messages = []
        again = train(
            _model(),
            x,
            data,
            settings,
            checkpoint_dir=tmp_path,
            progress=lambda fraction, message, said=messages: said.append(message),
        )
        assert "another run's checkpoint" in messages[0] and again.epochs_run == 1
    assert not list(tmp_path.glob("*.partial"))
