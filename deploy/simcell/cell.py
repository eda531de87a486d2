"""The configuration of a cell that runs against the simulated controller: the sections its
arm model and rated payload give."""

from __future__ import annotations


def cell_sections(description=None, rated_mass_kg: float | None = None) -> dict:
    """The ``[arm]`` and ``[gate]`` entries of a cell that runs against this controller on
    the arm model ``description`` (an :class:`~sim.description.ArmDescription`; None: the
    default): ``[arm] model`` (a named arm model by its name, else its file) and ``flange``,
    and ``[gate] rated_mass_kg`` when ``rated_mass_kg`` is given.

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
