"""MaskNet: a small convolutional encoder-decoder from the flow evidence to "not the world" per pixel.

A U-Net of four levels (the input's size, 1/2, 1/4, 1/8 of it), each one or two 3x3 convolutions (`CONVS`)
with batch norm and ReLU, the decoder upsampling (bilinear) and joining the encoder's level of the same size.
Input: `features.NUM_CHANNELS` channels at 1/4 of the frame size (`features.clip_features`); output:
one logit per pixel of the same size. About 52 thousand parameters (0.2 MB of float32). The per-motion network
(mosegpipe.masks.learned.which) is the same class with more inputs and output "which".

Inference runs in torch on the CPU with the process's thread count (`runtime.set_threads`; one by
default). The shipped weights (mosegpipe/weights/masknet.pt, whichnet.pt) are a plain dict of tensors and
settings, read with `torch.load(weights_only=True)`, offline.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F
from torch import nn

from mosegpipe.embed.architecture import weights_dir
from mosegpipe.errors import CheckpointError
from mosegpipe.io.read import atomic_write
from mosegpipe.masks.learned.features import NUM_CHANNELS

WIDTHS = (8, 16, 24, 32)
"""Channels per level of the encoder (and, mirrored, of the decoder): (8, 24, 48, 64) scored end to end 0.784
against 0.790 on the held-out development clips at twice the cost (docs/HISTORY.md, "Learned masks: a smaller
network")."""

CONVS = (1, 1, 2, 2)
"""3x3 convolutions per level (the decoder's too): one at the two largest sizes, where they cost most."""

WEIGHTS_FILES = {"moving": "masknet.pt", "which": "whichnet.pt"}
"""The shipped checkpoint's file name in mosegpipe/weights/ per output: what a checkpoint's logit means, "moving" = not
the world (`features.NUM_CHANNELS` inputs), "which" = the pixel is the queried motion's (`which.QUERY_CHANNELS`
more inputs, mosegpipe.masks.learned.which)."""


def _block(cin: int, cout: int, convs: int = 2) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(convs):
        layers += [nn.Conv2d(cin if i == 0 else cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout)]
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class MaskNet(nn.Module):
    """(B, C, h, w) features -> (B, 1, h, w) logits of `output` ("not the world", or "the queried motion's");
    any h, w >= 8."""

    def __init__(
        self, in_channels: int = NUM_CHANNELS, widths: tuple[int, ...] = WIDTHS, output: str = "moving"
    ) -> None:
        super().__init__()
        self.in_channels = in_channels
        self.widths = tuple(widths)
        self.output = output
        self.down = nn.ModuleList()
        cin = in_channels
        for i, w in enumerate(widths):
            self.down.append(_block(cin, w, CONVS[i]))
            cin = w
        self.up = nn.ModuleList(_block(widths[i + 1] + widths[i], widths[i], CONVS[i]) for i in range(len(widths) - 1))
        self.head = nn.Conv2d(widths[0], 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            if i > 0:
                x = F.max_pool2d(x, 2, ceil_mode=True)
            x = block(x)
            skips.append(x)
        for i in range(len(self.up) - 1, -1, -1):
            skip = skips[i]
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = self.up[i](torch.cat([x, skip], dim=1))
        out: torch.Tensor = self.head(x)
        return out

    def fused(self) -> MaskNet:
        """This network, in eval mode, with each batch norm folded into the convolution before it (the same
        function in fewer passes over the image: inference only)."""
        from torch.nn.utils.fusion import fuse_conv_bn_eval

        self.eval()
        for seq in [*self.down, *self.up]:
            for i in range(0, len(seq), 3):  # (Conv2d, BatchNorm2d, ReLU) per convolution
                conv, bn = seq[i], seq[i + 1]
                if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d):
                    seq[i], seq[i + 1] = fuse_conv_bn_eval(conv, bn), nn.Identity()
        return self

    def num_params(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def checkpoint(self, recipe: dict[str, Any] | None = None) -> dict[str, Any]:
        """A `torch.load(weights_only=True)`-loadable dict: the weights, the architecture, the recipe."""
        return {
            "kind": "masknet",
            "output": self.output,
            "in_channels": self.in_channels,
            "widths": list(self.widths),
            "state_dict": {k: v.detach().clone() for k, v in self.state_dict().items()},
            "recipe": recipe or {},
        }

    def save(self, path: str | Path, recipe: dict[str, Any] | None = None) -> None:
        with atomic_write(path) as tmp:  # a failed write (a full disk) leaves no temporary file
            torch.save(self.checkpoint(recipe), tmp)

    @classmethod
    def from_checkpoint(cls, path: str | Path, output: str = "moving") -> MaskNet:
        """The network of a checkpoint written by `save`, in eval mode.

        Raises:
            CheckpointError: the file is missing, unreadable, not a mask network's or not of `output`.
        """
        path = Path(path)
        if not path.is_file():
            raise CheckpointError(f"{path}: no mask network checkpoint there")
        try:
            ckpt = torch.load(path, weights_only=True, map_location="cpu")
        except Exception as exc:  # noqa: BLE001 - any unreadable file is one kind of error
            raise CheckpointError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc})") from exc
        if not isinstance(ckpt, dict) or ckpt.get("kind") != "masknet":
            raise CheckpointError(f"{path}: not a mask network checkpoint")
        if ckpt.get("output", "moving") != output:
            raise CheckpointError(f"{path}: a mask network of output {ckpt.get('output')!r}, not {output!r}")
        try:
            widths = tuple(int(w) for w in ckpt["widths"])
            if not 1 <= len(widths) <= len(CONVS) or min(widths) < 1:  # the levels the network is built of
                raise CheckpointError(
                    f"{path}: a mask network checkpoint with widths {list(widths)}; expected 1 to {len(CONVS)} "
                    "channel counts, each at least 1"
                )
            net = cls(int(ckpt["in_channels"]), widths, output)
            net.load_state_dict(ckpt["state_dict"])
        except (KeyError, RuntimeError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{path}: mask network checkpoint does not fit ({exc})") from exc
        net.recipe = dict(ckpt.get("recipe") or {})  # type: ignore[assignment]
        return net.eval()


def shipped_path(output: str = "moving") -> Path:
    """The shipped checkpoint of `output` (mosegpipe/weights/masknet.pt, whichnet.pt)."""
    return weights_dir() / WEIGHTS_FILES[output]


@functools.lru_cache(maxsize=4)
def load_masknet(path: str = "", output: str = "moving") -> MaskNet:
    """The mask network of checkpoint `path` ("" = the shipped one of `output`), loaded once per process."""
    net = MaskNet.from_checkpoint(Path(path) if path else shipped_path(output), output).fused()
    # channels last: oneDNN's convolutions without reordering, about half the time on one thread (640x480: 7 ms
    # against 13 per frame)
    return net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]


def predict(net: MaskNet, features: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """(T, h, w) float32 probabilities of "not the world" from (T, C, h, w) features."""
    if features.shape[1] != net.in_channels:
        raise CheckpointError(f"mask network expects {net.in_channels} input channels, got {features.shape[1]}")
    with torch.inference_mode():
        x = torch.from_numpy(np.ascontiguousarray(features)).contiguous(memory_format=torch.channels_last)
        logits = net(x)
        return torch.sigmoid(logits[:, 0]).numpy().astype(np.float32)
