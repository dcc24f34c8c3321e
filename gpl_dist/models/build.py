"""Building a policy network from a run's ``model`` section, and its weights as numpy arrays.

The one mapping from config to architecture (``build_model_from_config``), over both networks:
``gpl_dist.models.gpl.GPLPolicy`` and ``gpl_dist.models.mivoa.MIVOAPolicy``.
"""

from __future__ import annotations

from typing import Union

import numpy as np
import torch
from torch import nn

from gpl_dist.models.gpl import GPLPolicy
from gpl_dist.models.mivoa import MIVOA_VARIANTS, MIVOAPolicy
from gpl_dist.models.sizes import SIZE_FIELDS, Sizes
from gpl_dist.roles import DomainSpec

#: The networks ``build_model`` makes (``gpl_dist.roles.Policy``).
PolicyNetwork = Union[GPLPolicy, MIVOAPolicy]


def build_model(domain: DomainSpec, variant: str = "gpl", embedding_dim: int = 16, seed: int | None = None,
                policy_batchnorm: bool = False, paraphrases: bool = False,
                linear_encodings: bool = False, conv_batchnorm: bool = False,
                encoder_layernorm: bool = False, correction_width: int = 0,
                encoder_activation: str = "relu", sizes: Sizes | None = None) -> "PolicyNetwork":
    """A freshly initialised model of ``variant`` (deterministic when ``seed`` is given): a
    ``GPLPolicy``, or for the MIVOA variants a ``gpl_dist.models.mivoa.MIVOAPolicy``; with
    ``paraphrases``, it reads the words of the domain's training paraphrases too;
    ``linear_encodings``, ``encoder_layernorm`` and ``correction_width`` (GPL's encoders; MIVOA has its own),
    ``conv_batchnorm`` (every grid state encoder, MIVOA's too): see ``gpl_dist.config.ModelConfig``;
    ``sizes``: layer sizes in place of the domain's ``model_sizes``."""
    def make() -> "PolicyNetwork":
        if variant in MIVOA_VARIANTS:
            return MIVOAPolicy(domain, variant, embedding_dim, policy_batchnorm, paraphrases, conv_batchnorm, sizes)
        return GPLPolicy(domain, variant, embedding_dim, policy_batchnorm, paraphrases, linear_encodings, conv_batchnorm,
                         encoder_layernorm, correction_width, encoder_activation, sizes)

    if seed is not None:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            return make()
    return make()


def build_model_from_config(domain: DomainSpec, model_cfg, seed: int | None = None) -> "PolicyNetwork":
    """The model a run's ``model`` section (``gpl_dist.config.ModelConfig``) describes: the one
    mapping from config to architecture, so learner, evaluation and analyses cannot disagree."""
    return build_model(domain, model_cfg.variant, model_cfg.embedding_dim, seed=seed,
                       policy_batchnorm=model_cfg.policy_batchnorm, paraphrases=model_cfg.paraphrases,
                       linear_encodings=model_cfg.linear_encodings, conv_batchnorm=model_cfg.conv_batchnorm,
                       encoder_layernorm=model_cfg.encoder_layernorm, correction_width=model_cfg.correction_width,
                       encoder_activation=model_cfg.encoder_activation, sizes=model_sizes(domain, model_cfg))


def model_sizes(domain: DomainSpec, model_cfg) -> Sizes:
    """The layer sizes a run's ``model`` section gives: the domain's, with each size the section
    sets (``model.policy_mlp`` ...) in its place."""
    return domain.model_sizes.overridden({name: getattr(model_cfg, name, None) for name in SIZE_FIELDS})


def state_dict_to_numpy(model: nn.Module) -> dict[str, np.ndarray]:
    """Weights as plain numpy arrays: cheap to ``ray.put`` and safe to ship (no pickled code)."""
    return {k: v.detach().cpu().numpy().copy() for k, v in model.state_dict().items()}


def load_numpy_state(model: nn.Module, weights: dict[str, np.ndarray]) -> None:
    """Load weights given as numpy arrays (as ``state_dict_to_numpy`` makes them) into ``model``."""
    model.load_state_dict({k: torch.tensor(np.asarray(v)) for k, v in weights.items()})
