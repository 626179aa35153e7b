"""The radiance field F_theta: (x, d) -> (c, sigma), the MLP of Section 3 (architecture in Fig. 7)."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from nerfpipe.nerf.fields.configs import MlpConfig
from nerfpipe.nerf.fields.encoding import encoded_size, positional_encoding


class NerfField(nn.Module):
    """8 fully connected ReLU layers of 256 channels on gamma(x), gamma(x) concatenated again to the fifth
    layer's input; a linear density head sigma (ReLU) and a 256-d feature; the feature concatenated with
    gamma(d) through one 128-channel ReLU layer; RGB through a sigmoid (Section 3, Fig. 7).

    Without view dependence (Table 2, row 3) the 128-channel layer sees the feature alone. Without
    positional encoding (``pos_freqs = dir_freqs = 0``) the raw coordinates go in.
    """

    def __init__(self, config: MlpConfig = MlpConfig()) -> None:
        super().__init__()
        self.config = config
        self.pos_freqs = config.pos_freqs if config.positional_encoding else 0
        self.dir_freqs = config.dir_freqs if config.positional_encoding else 0
        self.skips = config.skips()
        include = config.include_input or self.pos_freqs == 0
        self.pos_include = include
        self.dir_include = config.include_input or self.dir_freqs == 0
        pos_dim = encoded_size(self.pos_freqs, include)
        dir_dim = encoded_size(self.dir_freqs, self.dir_include) if config.view_dependence else 0
        layers, in_dim = [], pos_dim
        for i in range(config.depth):
            layers.append(nn.Linear(in_dim, config.width))
            in_dim = config.width + (pos_dim if i in self.skips else 0)
        self.trunk = nn.ModuleList(layers)
        self.density = nn.Linear(config.width, 1)
        self.feature = nn.Linear(config.width, config.width)
        self.view = nn.Linear(config.width + dir_dim, config.view_width)
        self.rgb = nn.Linear(config.view_width, 3)

    @classmethod
    def from_config(cls, config: MlpConfig, box: Any = None) -> "NerfField":
        """The MLP takes any point: ``box`` is not read."""
        return cls(config)

    def box(self) -> None:
        return None

    def density_activation(self, raw: Tensor) -> Tensor:
        if self.config.density_activation == "softplus":
            return nn.functional.softplus(raw - 1.0)  # shifted so empty space starts nearly transparent
        return torch.relu(raw)

    def trunk_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """x: (M, 3) positions -> (raw density (M,), feature (M, width))."""
        encoded = positional_encoding(x, self.pos_freqs, self.pos_include)
        h = encoded
        for i, layer in enumerate(self.trunk):
            h = torch.relu(layer(h))
            if i in self.skips:
                h = torch.cat([h, encoded], dim=-1)
        return self.density(h).squeeze(-1), self.feature(h)

    def forward(self, x: Tensor, d: Tensor | None = None, density_noise: float = 0.0) -> tuple[Tensor, Tensor]:
        """Evaluate the field.

        Args:
            x: (M, 3) positions; d: (M, 3) unit viewing directions (ignored without view dependence).
            density_noise: std of Gaussian noise added to the raw density before its activation, the
                regularizer the authors apply to real scenes.
        Returns:
            rgb: (M, 3) in (0, 1); sigma: (M,) >= 0.
        """
        raw_sigma, feature = self.trunk_features(x)
        if density_noise > 0:
            raw_sigma = raw_sigma + density_noise * torch.randn_like(raw_sigma)
        return self.colour(feature, d), self.density_activation(raw_sigma.float())

    def density_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """sigma (M,) and the trunk's feature (M, width) ``colour`` reads, of (M, 3) positions."""
        raw_sigma, feature = self.trunk_features(x)
        return self.density_activation(raw_sigma.float()), feature

    def colour(self, feature: Tensor, d: Tensor | None) -> Tensor:
        """rgb (M, 3) in (0, 1) from the trunk's feature and unit viewing directions d (M, 3)."""
        if self.config.view_dependence:
            if d is None:
                raise ValueError("a view-dependent field needs viewing directions d")
            feature = torch.cat([feature, positional_encoding(d, self.dir_freqs, self.dir_include).to(feature.dtype)], dim=-1)
        return torch.sigmoid(self.rgb(torch.relu(self.view(feature))).float())

    def query_density(self, x: Tensor) -> Tensor:
        """sigma(x) alone: (M, 3) -> (M,), without the colour branch (for meshes and occupancy)."""
        return self.density_activation(self.trunk_features(x)[0].float())

    def flops_per_sample(self) -> int:
        """Multiply-adds x 2 of one forward evaluation (the linear layers; activations are negligible)."""
        return 2 * sum(m.in_features * m.out_features for m in self.modules() if isinstance(m, nn.Linear))
