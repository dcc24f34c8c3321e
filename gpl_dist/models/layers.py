"""The layers GPL and MIVOA share: the batch record they are conditioned on (``Conditioning``), the
grid and vector state encoders, the text and value encoders, and the MLP builder.

The grid state encoder's first 2x2 convolution is a lookup of summed weight columns
(``GridStateEncoder``); the kernel-2 1-D convolutions run channels-last
(``conv1d_k2_channels_last``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from gpl_dist.config import ENCODER_ACTIVATIONS
from gpl_dist.roles import DomainSpec


@dataclass(frozen=True)
class Conditioning:
    """What a batch of attempts is conditioned on.

    ``A`` attempts share ``U`` distinct earlier attempts: each earlier (trajectory, correction) pair
    is encoded once, however many later attempts in the batch are conditioned on it.

    Attributes:
        instruction_ids: int64 ``(A, L)`` each attempt's instruction.
        trajectories: ``(U, S, *O)`` subsampled earlier attempts (obs dtype).
        correction_ids: int64 ``(U, L)`` the correction given after each earlier attempt.
        slots: int64 ``(A, K)`` rows of ``trajectories`` each attempt is conditioned on, oldest
            first, padded with -1.
        instruction_values: float32 ``(A, F)`` numeric full information in place of the
            instruction (``DomainSpec.full_information_values``), or None.
        correction_values: float32 ``(U,)`` each earlier attempt's summed reward (GPR's feedback
            in place of the correction), or None.
    """

    instruction_ids: torch.Tensor
    trajectories: torch.Tensor
    correction_ids: torch.Tensor
    slots: torch.Tensor
    instruction_values: torch.Tensor | None = None
    correction_values: torch.Tensor | None = None

    def to(self, device: torch.device | str) -> "Conditioning":
        move = lambda t: t.to(device, non_blocking=True)  # noqa: E731
        maybe = lambda t: None if t is None else move(t)  # noqa: E731
        return Conditioning(move(self.instruction_ids), move(self.trajectories), move(self.correction_ids), move(self.slots),
                            maybe(self.instruction_values), maybe(self.correction_values))


#: The activations of GPL's conditioning encoders (``ModelConfig.encoder_activation``): name -> module
#: class. LeakyReLU (slope 0.01) has no dead zone: under Adam, whose steps do not shrink with the
#: gradient, a unit that is never positive still moves back.
ACTIVATIONS: dict[str, type[nn.Module]] = dict(zip(ENCODER_ACTIVATIONS, (nn.ReLU, nn.LeakyReLU), strict=True))


def mlp(sizes: tuple[int, ...], in_dim: int, final_activation: bool = True,
        batchnorm: bool = False, hidden_layernorm: bool = False,
        activation: str = "relu") -> tuple[nn.Sequential, int]:
    """Linear layers of ``sizes``, ``activation`` (one of ``ACTIVATIONS``) between them (and after
    the last with ``final_activation``); ``batchnorm`` puts a BatchNorm1d after every linear layer,
    ``hidden_layernorm`` a LayerNorm after every hidden one (per sample: it holds for a batch of one
    attempt row as in training)."""
    layers: list[nn.Module] = []
    d = in_dim
    for i, h in enumerate(sizes):
        layers.append(nn.Linear(d, h))
        if batchnorm:
            layers.append(nn.BatchNorm1d(h))
        elif hidden_layernorm and i < len(sizes) - 1:
            layers.append(nn.LayerNorm(h))
        if final_activation or i < len(sizes) - 1:
            layers.append(ACTIVATIONS[activation]())
        d = h
    return nn.Sequential(*layers), d


class _ShiftSum(torch.autograd.Function):
    """Sum of the 2 taps of a kernel-2, stride-1 convolution over a sequence whose taps were
    projected separately: ``(B, L, 2, o)`` -> ``(B, L-1, o)``. Written as a function because
    autograd's backward of two overlapping slices zero-fills a full-size buffer per slice and adds
    them up; this backward fills one buffer once.
    """

    @staticmethod
    def forward(ctx, y: torch.Tensor) -> torch.Tensor:
        ctx.y_shape = y.shape
        return y[:, :-1, 0] + y[:, 1:, 1]

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        gy = grad.new_zeros(ctx.y_shape)
        gy[:, :-1, 0] = grad
        gy[:, 1:, 1] = grad
        return gy


class _FirstConv2x2(torch.autograd.Function):
    """A 2x2 convolution (stride 1) of one-hot grid cells, from per-group lookup tables.

    ``table (R, 4 * out)``: for each channel group's code combinations (groups stacked, ``R`` rows
    in all), the projection onto the 4 taps; ``rows (B, H, W, G)``: each cell's row per group
    (global row indices). Output ``(B, H-1, W-1, out)``.

    Forward: one ``embedding_bag`` sum over the 4 taps x G groups of each output cell (no
    ``(B, H, W, 4 * out)`` intermediate). Backward: the tap gradients of each *cell* (one buffer,
    the output gradient written shifted once per tap), then one ``index_add_`` per
    group over ``B*H*W`` rows of width ``4 * out``:
    4x fewer, wider rows than adding per output cell and tap, which is what makes it fast on a CPU.
    """

    @staticmethod
    def forward(ctx, table: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        b, h, w, g = rows.shape
        r, out = table.shape[0], table.shape[1] // 4
        taps = table.view(r, 4, out).transpose(0, 1).reshape(4 * r, out)  # row k * R + i: tap k of row i
        windows = [rows[:, di:di + h - 1, dj:dj + w - 1] + k * r for k, (di, dj) in enumerate(_TAPS)]
        bags = torch.cat(windows, dim=-1).view(-1, 4 * g)
        ctx.save_for_backward(rows)
        ctx.table_shape = table.shape
        return nn.functional.embedding_bag(bags, taps, mode="sum").view(b, h - 1, w - 1, out)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (rows,) = ctx.saved_tensors
        b, h, w, g = rows.shape
        out = grad.shape[-1]
        # cell (i, j) feeds output (i - di, j - dj) through tap k: tap k's gradient over the cells is
        # the output gradient shifted by (di, dj), zero where the tap feeds no output; the four taps
        # side by side are each cell's row
        per_cell = grad.new_zeros(b, h, w, 4, out)
        for k, (di, dj) in enumerate(_TAPS):
            per_cell[:, di:di + h - 1, dj:dj + w - 1, k] = grad
        per_cell = per_cell.view(-1, 4 * out)
        grad_table = grad.new_zeros(ctx.table_shape)
        for j in range(g):
            grad_table.index_add_(0, rows[..., j].reshape(-1), per_cell)
        return grad_table, None


_TAPS = ((0, 0), (0, 1), (1, 0), (1, 1))


class Conv2x2(nn.Module):
    """``Conv2d(kernel_size=2, stride=1)`` on channels-last input ``(B, H, W, D)`` -> ``(B, H-1, W-1, out)``.

    ``proj.weight`` holds the 4 taps (0,0), (0,1), (1,0), (1,1) as consecutive blocks of ``out``
    rows: a one-hot input's projection is then a lookup (``GridStateEncoder.group_tables``). On
    dense input (the later layers) MKL-DNN's convolution is the fastest form measured.
    """

    def __init__(self, in_dim: int, out_dim: int):
        super().__init__()
        self.out_dim = out_dim
        self.proj = nn.Linear(in_dim, 4 * out_dim, bias=False)
        bound = 1.0 / np.sqrt(4 * in_dim)  # Conv2d's default initialisation, fan_in = 4 * in_dim
        nn.init.uniform_(self.proj.weight, -bound, bound)
        self.bias = nn.Parameter(torch.empty(out_dim).uniform_(-bound, bound))

    def kernel(self) -> torch.Tensor:
        """``(out, in, 2, 2)``: ``proj.weight`` as a ``Conv2d`` kernel."""
        return self.proj.weight.view(2, 2, self.out_dim, -1).permute(2, 3, 0, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # the NCHW view of channels-last x is MKL-DNN's channels_last format: no reorder either way
        y = nn.functional.conv2d(x.permute(0, 3, 1, 2), self.kernel(), self.bias)
        return y.permute(0, 2, 3, 1)


def conv1d_k2_channels_last(conv: nn.Conv1d, x: torch.Tensor) -> torch.Tensor:
    """``conv`` (kernel 2, stride 1) applied to channels-last ``(B, L, E)`` -> ``(B, L-1, out)``.

    The same function as ``conv(x.transpose(1, 2)).transpose(1, 2)`` with ``conv``'s own
    parameters (checkpoints are unchanged), as one matrix product and a shifted sum: cheaper than
    MKL-DNN's convolution for sequences of a few steps.
    """
    out = conv.out_channels
    w = conv.weight.permute(2, 0, 1).reshape(2 * out, conv.in_channels)  # taps stacked
    y = nn.functional.linear(x, w)
    return _ShiftSum.apply(y.view(*y.shape[:2], 2, out)) + conv.bias


def channel_groups(categories: tuple[int, ...], max_rows: int = 1024) -> list[tuple[int, ...]]:
    """Consecutive channels grouped while the product of their category counts stays <= max_rows."""
    groups: list[list[int]] = []
    rows = max_rows + 1
    for c, n in enumerate(categories):
        if rows * n > max_rows:
            groups.append([])
            rows = 1
        groups[-1].append(c)
        rows *= n
    return [tuple(g) for g in groups]


class GridStateEncoder(nn.Module):
    """uint8 grid ``(B, H, W, C)`` -> vector: 2x2 convolutions (stride 1) then an MLP, as in the appendix.

    Every channel holds a categorical code, so the input is the one-hot encoding of each channel
    (``categories[c]`` codes for channel ``c``), not the raw integers; the convolutions are
    ``Conv2x2`` layers in channels-last form.

    ``batchnorm`` normalises each convolution's output channels (over batch and cells) before its
    ReLU, as the authors' code does (``model.conv_batchnorm``).

    The first layer never builds the one-hot tensor: the projection of a one-hot cell is a sum of
    weight columns, so channels are grouped (``channel_groups``), each group's code combinations
    get a row of summed columns (``group_tables``), and each output cell sums the rows of its
    4 taps x G groups (``group_rows``, ``_FirstConv2x2``). The same function and parameters
    as the one-hot convolution, several times cheaper forward and backward.
    """

    def __init__(self, obs_shape: tuple[int, ...], categories: tuple[int, ...], channels: tuple[int, ...],
                 mlp_sizes: tuple[int, ...], batchnorm: bool = False, mlp_activation: str = "relu"):
        super().__init__()
        h, w, c = obs_shape
        if len(categories) != c:
            raise ValueError(f"need one category count per channel ({c}), got {categories}")
        self.categories = tuple(categories)
        self.num_inputs = int(sum(categories))
        offsets = [0, *np.cumsum(categories)[:-1].tolist()]
        self.groups = channel_groups(categories)
        # code combination index of each group: obs (.., C) @ row_weights (C, G), plus the rows of
        # the groups before it in group_tables()
        row_weights = np.zeros((c, len(self.groups)), np.float32)
        starts, total = [], 0
        for i, group in enumerate(self.groups):
            counts = [categories[ch] for ch in group]
            combos = np.stack(np.meshgrid(*[np.arange(n) for n in counts], indexing="ij"), -1).reshape(-1, len(group))
            columns = combos + np.array([offsets[ch] for ch in group])  # one-hot column of each channel's code
            self.register_buffer(f"group_columns_{i}", torch.from_numpy(columns).long(), persistent=False)
            row_weights[list(group), i] = np.cumprod([1, *counts[::-1]])[:-1][::-1]  # row = codes . strides
            starts.append(total)
            total += len(combos)
        self.register_buffer("row_weights", torch.from_numpy(row_weights), persistent=False)
        self.register_buffer("group_starts", torch.tensor(starts, dtype=torch.long), persistent=False)
        widths = (self.num_inputs, *channels)
        self.convs = nn.ModuleList(Conv2x2(a, b) for a, b in zip(widths[:-1], widths[1:]))
        self.norms = nn.ModuleList(nn.BatchNorm1d(ch) for ch in channels) if batchnorm else None
        h, w = h - len(channels), w - len(channels)
        self.mlp, self.out_dim = mlp(mlp_sizes, channels[-1] * h * w, activation=mlp_activation)

    def group_tables(self) -> torch.Tensor:
        """``(R, 4 * out)``: the first layer's projection of every code combination of every
        channel group (groups stacked), i.e. ``convs[0].proj`` of the combination's one-hot."""
        weight_t = self.convs[0].proj.weight.t()  # type: ignore[union-attr,operator]  # (num_inputs, 4 * out)
        return torch.cat([weight_t[getattr(self, f"group_columns_{i}")].sum(1) for i in range(len(self.groups))])

    def group_rows(self, obs: torch.Tensor) -> torch.Tensor:
        """int64 ``(B, H, W, G)``: each cell's row of ``group_tables`` per channel group."""
        # one small matmul gives every group's combination index (exact: indices stay below 2^24)
        # registered buffers read as Tensor | Module to a type checker
        rows = obs.to(self.row_weights.dtype) @ self.row_weights  # type: ignore[arg-type,operator]
        return rows.long() + self.group_starts  # type: ignore[operator]

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        first = self.convs[0]
        x = torch.relu(self._norm(0, _FirstConv2x2.apply(self.group_tables(), self.group_rows(obs)) + first.bias))
        for i, conv in enumerate(self.convs[1:], start=1):
            x = torch.relu(self._norm(i, conv(x)))
        return self.mlp(x.reshape(x.shape[0], -1))

    def _norm(self, layer: int, x: torch.Tensor) -> torch.Tensor:
        """Channels-last ``x (B, H, W, C)`` through layer ``layer``'s BatchNorm, if any (BatchNorm1d
        over ``(B * H * W, C)`` is BatchNorm2d's function)."""
        if self.norms is None:
            return x
        return self.norms[layer](x.reshape(-1, x.shape[-1])).reshape(x.shape)


class VectorStateEncoder(nn.Module):
    """float vector ``(B, D)`` -> the same vector, normalised by running statistics."""

    def __init__(self, obs_shape: tuple[int, ...]):
        super().__init__()
        self.norm = nn.BatchNorm1d(obs_shape[0])
        self.out_dim = obs_shape[0]

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.norm(obs.float())


def grid_categories(domain: DomainSpec) -> tuple[int, ...]:
    """The number of codes of each channel of ``domain``'s grid observations (``DomainSpec.obs_categories``)."""
    if domain.obs_categories is None:
        raise ValueError(f"domain {domain.name} has grid observations but no obs_categories")
    return domain.obs_categories


class TextEncoder(nn.Module):
    """Token ids ``(B, L)`` -> vector: shared embeddings, 1-D CNN (kernel 2), MLP."""

    def __init__(self, embedding: nn.Embedding, max_tokens: int, conv: int, mlp_sizes: tuple[int, ...],
                 final_activation: bool = True, hidden_layernorm: bool = False, activation: str = "relu"):
        super().__init__()
        self.embedding = embedding
        self.conv = nn.Conv1d(embedding.embedding_dim, conv, kernel_size=2)
        self.conv_activation = ACTIVATIONS[activation]()
        self.mlp, self.out_dim = mlp(mlp_sizes, conv * (max_tokens - 1), final_activation,
                                     hidden_layernorm=hidden_layernorm, activation=activation)

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        x = self.conv_activation(conv1d_k2_channels_last(self.conv, self.embedding(ids)))  # (B, L-1, conv)
        return self.mlp(x.transpose(1, 2).flatten(1))  # channel-major, as Conv1d's output


class ValueEncoder(nn.Module):
    """float32 ``(B, F)`` numbers -> vector: an MLP (numeric full information)."""

    def __init__(self, width: int, mlp_sizes: tuple[int, ...], final_activation: bool = True,
                 hidden_layernorm: bool = False, activation: str = "relu"):
        super().__init__()
        self.mlp, self.out_dim = mlp(mlp_sizes, width, final_activation, hidden_layernorm=hidden_layernorm,
                                     activation=activation)

    def forward(self, values: torch.Tensor) -> torch.Tensor:
        return self.mlp(values.float())
