"""The model directory (docs/learn.md): ``config.json`` and ``weights.npz``.

The weights are plain arrays in an npz (read with ``allow_pickle=False``: no code runs
on loading), and the config records each weight file's SHA-256, so a file altered or
swapped after training is refused rather than silently predicting something else.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_path, atomic_write_text
from camwhisker.files.digest import sha256_file
from camwhisker.learn.knn import WindowKnn
from camwhisker.learn.net import build_net, import_torch
from camwhisker.learn.series import Columns, LearnError, Normalisation

__all__ = ["MODEL_FORMAT", "CONFIG", "WEIGHTS", "Model", "save_model", "load_model"]

#: Bumped when a change makes older model directories unreadable (refused, not guessed at).
MODEL_FORMAT = 1
CONFIG, WEIGHTS = "config.json", "weights.npz"


@dataclass
class Model:
    net: object
    columns: Columns
    window: int
    norm: Normalisation
    config: dict


def save_model(out: str | Path, net, columns: Columns, window: int, norm: Normalisation,
               arch: dict, summary: dict) -> Path:  # fmt: skip
    """Write the model directory ``out`` (created; its two files replaced atomically,
    the config last, so a reader never pairs a new config with old weights)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise LearnError(f"{out}: exists and is not a directory")
    if isinstance(net, WindowKnn):
        state = net.state()
    else:
        state = {k: v.detach().cpu().numpy() for k, v in net.state_dict().items()}
    with atomic_path(out / WEIGHTS) as tmp:
        np.savez(tmp, **state)
    config = {
        "format": MODEL_FORMAT,
        "camwhisker_version": __version__,
        "inputs": list(columns.inputs),
        "targets": list(columns.targets),
        "angle_targets": list(columns.angle_targets),
        "window": window,
        "architecture": arch,
        "normalisation": norm.to_json(),
        "weights": {WEIGHTS: sha256_file(out / WEIGHTS)},
        "training": summary,
    }
    atomic_write_text(out / CONFIG, jsonfile.dumps(config, indent=1) + "\n")
    return out


def _read_config(model: Path) -> dict:
    path = model / CONFIG
    if not model.is_dir():
        raise LearnError(f"{model}: not a model directory (camwhisker learn --out writes one)")
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LearnError(f"{path}: missing; {model} is not a complete model directory") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise LearnError(f"{path}: cannot read the model's config ({exc})") from None
    if not isinstance(config, dict) or config.get("format") != MODEL_FORMAT:
        fmt = config.get("format") if isinstance(config, dict) else None
        by = config.get("camwhisker_version", "?") if isinstance(config, dict) else "?"
        raise LearnError(f"{path}: model format {fmt!r} (written by camwhisker {by}); this "
                         f"camwhisker {__version__} reads format {MODEL_FORMAT}: train it again")
    need = ("inputs", "targets", "angle_targets", "window", "architecture", "normalisation",
            "weights")  # fmt: skip
    missing = [k for k in need if k not in config]
    if missing:
        raise LearnError(f"{path}: missing key(s) {', '.join(missing)}")
    return config


def load_model(model: str | Path) -> Model:
    """Read a model directory: the config checked, each weight file's SHA-256 checked.

    Raises
    ------
    LearnError
        Naming the file: missing, unreadable, of another format, or altered since training.
    """
    model = Path(model)
    config = _read_config(model)
    for name, digest in config["weights"].items():
        path = model / name
        if not path.is_file():
            raise LearnError(f"{path}: missing; {model} is not a complete model directory")
        if sha256_file(path) != digest:
            raise LearnError(f"{path}: altered since training (its SHA-256 is not the one "
                             f"{model / CONFIG} records)")
    columns = Columns(tuple(config["inputs"]), tuple(config["targets"]),
                      tuple(config["angle_targets"]))  # fmt: skip
    try:
        norm = Normalisation.from_json(config["normalisation"])
        window = int(config["window"])
        with np.load(model / WEIGHTS, allow_pickle=False) as npz:
            state = {k: npz[k] for k in npz.files}
        net = _estimator(config["architecture"], state, columns, window)
    except (KeyError, TypeError, RuntimeError, ValueError) as exc:
        raise LearnError(f"{model}: the config and weights do not make a model "
                         f"({str(exc).splitlines()[0]})") from None
    return Model(net, columns, window, norm, config)


def _estimator(arch: dict, state: dict, columns: Columns, window: int):
    """The model of ``arch``'s kind from its stored arrays (torch only for a network)."""
    if arch.get("kind") == "knn":
        if state["rows"].shape[1] != len(columns.inputs) or \
                state["targets"].shape[1] != len(columns.all_targets):
            raise ValueError("the stored rows do not match the config's columns")
        return WindowKnn(state["rows"], state["targets"], state["lengths"], window,
                         len(columns.angle_targets), k=int(arch["k"]))  # fmt: skip
    torch = import_torch()
    net = build_net(arch, len(columns.inputs), columns.n_encoded)
    net.load_state_dict({k: torch.from_numpy(v) for k, v in state.items()})
    net.eval()
    return net
