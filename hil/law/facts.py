"""What hil knows of a [controller] law from its name alone, one table (the laws themselves are
controller_service.registry's): which has the sampled-data certificate, which keeps a boundary
layer, which runs on numpy arrays as well as on floats."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from controller_service.registry import BUILTIN_LAWS

#: The laws the certificate (docs/sampled_data_bound.md) covers: the paper's unified law, with
#: or without its boundary layer.
CERTIFIED_LAWS = ("unified", "unified_boundary")
BOUNDARY_LAYER_LAW = "unified_boundary"
#: The laws with the sliding variables v~ = v − α_v, w~ = ω − α_ω of (10) (their telemetry's
#: v_tilde, w_tilde): the unified law's. [7], [19] and a user's law (a PD loop) have none.
SLIDING_LAWS = CERTIFIED_LAWS


@dataclass(frozen=True)
class Law:
    """A [controller] law by its name (a built-in's, or a user's ``module:Class``)."""

    name: str

    @classmethod
    def of(cls, controller: Mapping[str, Any]) -> Law:
        """The law of a [controller] table (its default: the unified law)."""
        return cls(str(controller.get("law", "unified")))

    @property
    def builtin(self) -> bool:
        return self.name in BUILTIN_LAWS

    @property
    def has_certificate(self) -> bool:
        return self.name in CERTIFIED_LAWS

    @property
    def boundary_layer(self) -> bool:
        return self.name == BOUNDARY_LAYER_LAW

    @property
    def sliding_variables(self) -> bool:
        """True for a law with the sliding variables v~, w~ of (10), which a page explains."""
        return self.name in SLIDING_LAWS

    @property
    def takes_arrays(self) -> bool:
        """True for the built-in laws; a user's law is tried on arrays before it is trusted."""
        return self.builtin
