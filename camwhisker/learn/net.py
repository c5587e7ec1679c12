"""The network, in torch (imported here only, so the core package runs without it).

It reads a window shape (B, window, n_inputs) of normalised inputs and gives the encoded
target shape (B, n_encoded) at the window's last row: causal dilated 1-D convolutions,
chosen over a GRU and a ridge model by ``camwhisker dev learn-bench compare``.
"""

from __future__ import annotations

from camwhisker.learn.series import LearnError

__all__ = ["import_torch", "ARCHITECTURES", "conv_dilations", "build_net"]

#: The extra that installs torch (pyproject.toml), named in the error when it is missing.
INSTALL_HINT = ("pip install torch==2.13.0 && pip install 'camwhisker[learn]' "
                "(torch 2.13.0 first: the CPU build)")  # fmt: skip


def import_torch():
    """torch, or a LearnError saying how to install it."""
    try:
        import torch
    except ImportError:
        raise LearnError(f"learn and predict need torch, which is not installed: "
                         f"{INSTALL_HINT}") from None
    return torch


def conv_dilations(window: int) -> list[int]:
    """Dilations 1, 2, 4, ... of kernel-3 layers until the last row sees the whole window."""
    dilations = [1]
    while 1 + 2 * sum(dilations) < window:
        dilations.append(2 * dilations[-1])
    return dilations


def _conv(torch, n_inputs: int, n_out: int, hidden: int, dilations: list[int]):
    nn = torch.nn

    class WindowConv(nn.Module):
        def __init__(self):
            super().__init__()
            chans = [n_inputs] + [hidden] * len(dilations)
            self.convs = nn.ModuleList(
                nn.Conv1d(a, b, 3, dilation=d) for a, b, d in zip(chans, chans[1:], dilations,
                                                                  strict=False))
            self.head = nn.Linear(hidden, n_out)

        def forward(self, x):
            h = x.transpose(1, 2)
            for i, conv in enumerate(self.convs):
                d = conv.dilation[0]
                # Only the rows the later layers read reach the last row: compute those.
                keep = min(h.shape[2], 1 + 2 * sum(dilations[i + 1 :]))
                h = nn.functional.pad(h, (2 * d, 0))[:, :, -(keep + 2 * d) :]  # causal
                h = torch.relu(conv(h))
            return self.head(h[:, :, -1])

    return WindowConv()


ARCHITECTURES = {"conv": _conv}


def build_net(arch: dict, n_inputs: int, n_out: int):
    """The network ``arch`` (``{"kind": ..., "hidden": ..., "dilations": ...}``) describes,
    fresh weights."""
    torch = import_torch()
    if arch.get("kind") not in ARCHITECTURES:
        raise LearnError(f"unknown architecture {arch.get('kind')!r} (known: "
                         f"{', '.join(ARCHITECTURES)})")
    return ARCHITECTURES[arch["kind"]](torch, n_inputs, n_out, int(arch["hidden"]),
                                       [int(d) for d in arch.get("dilations", [1])])
