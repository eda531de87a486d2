"""A cell's configuration built in code, not read from a file (the demo, a replay, the
benchmarks that run the service): its ``[arm]`` and ``[gate]`` from the arm model and its
rated payload, the sections the caller gives, checked as a ``cell.toml`` is."""

from __future__ import annotations

from .load import config_from_dict
from .sections import CellConfig


def cell_sections(description=None, rated_mass_kg: float | None = None) -> dict:
    """The ``[arm]`` and ``[gate]`` entries of a cell on the arm model ``description`` (an
    :class:`~sim.description.ArmDescription`; None: the default): ``[arm] model`` (a named
    arm model by its name, else its file) and ``flange``, and ``[gate] rated_mass_kg`` when
    ``rated_mass_kg`` is given.

    Raises:
        iem.errors.InvalidInputError: an arm model from a file, which gives no rated
            payload, without ``rated_mass_kg`` (``--rated-mass-kg``)."""
    from iem.errors import InvalidInputError

    if description is not None and description.rated_payload_kg is None \
            and rated_mass_kg is None:
        raise InvalidInputError(f"the arm model {description.name!r} ({description.source}) "
                                "gives no rated payload, which the gate checks; give the arm "
                                "maker's rated payload with --rated-mass-kg KG")
    out: dict = {"arm": {}, "gate": {}}
    if description is not None:
        out["arm"] = {"model": description.source_spec, "flange": description.flange}
    if rated_mass_kg is not None:
        out["gate"]["rated_mass_kg"] = float(rated_mass_kg)
    return out


def cell_config(description=None, rated_mass_kg: float | None = None, *, where: str,
                status: bool = False, arm: dict | None = None, gate: dict | None = None,
                **sections) -> CellConfig:
    """The configuration of a cell on the arm model ``description`` (None: the default)
    whose gate is rated for ``rated_mass_kg`` (None: the arm model's rated payload)
    (:func:`cell_sections`), with more ``[arm]`` and ``[gate]`` keys in ``arm`` and
    ``gate``, the status line on or off, and the other ``sections`` as given (``link``,
    ``model``, ``host``, ``estimate``). A cell whose ``[model] kind`` is the paper's IEM,
    which reports no uncertainty, lets the gate write without it
    (``allow_without_uncertainty``). ``where`` names the cell in errors.

    Raises:
        iem.errors.InvalidInputError: as :func:`cell_sections`.
        deploy.config.ConfigError: a section, key or value a ``cell.toml`` may not hold,
            e.g. an end effector that leaves no payload within the rating."""
    cell = cell_sections(description, rated_mass_kg)
    allow = {"allow_without_uncertainty": True} \
        if sections.get("model", {}).get("kind") == "IEM" else {}
    return config_from_dict({
        **sections,
        "arm": {**cell["arm"], **(arm or {})},
        "gate": {**cell["gate"], **allow, **(gate or {})},
        "log": {"status_line": "on" if status else "off", **sections.get("log", {})},
    }, where=where)
