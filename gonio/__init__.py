"""gonio: control and acquisition for gonio-reflectometers (README.md, docs/).

Importing :mod:`gonio` imports nothing else: each module pulls in what it needs.
"""

from __future__ import annotations

__all__ = ["SEED_MAX", "software_version"]

#: The largest seed of simulated devices' random numbers: a campaign's seed is stored as a 64-bit signed
#: integer (brdf.h5's ``seed`` attribute, a batch store's ``seed`` coordinate), so every entry point (the
#: CLI's ``--seed``, the daemon's requests, :func:`gonio.campaign.create_campaign`) refuses more.
SEED_MAX = 2**63 - 1


def software_version() -> str:
    """The installed version of gonio (``0+unknown`` in a source tree that was never installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gonio")
    except PackageNotFoundError:
        return "0+unknown"
