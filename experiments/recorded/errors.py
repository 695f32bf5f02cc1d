"""The error a malformed recorded pass raises (``docs/pass-format.md``)."""

from __future__ import annotations

from attopt.formulations.errors import AttoptError


class PassFormatError(AttoptError, ValueError):
    """A recorded pass that does not follow the format: the message names the file or
    table, the column or key, and the row.

    Example::

        >>> from attopt.experiments.recorded import PassFormatError
        >>> str(PassFormatError.at("vectors", "sigma_rad", 3, "must be finite and positive"))
        'table vectors, column sigma_rad, row 3: must be finite and positive'
    """

    @classmethod
    def at(
        cls, table: str, column: str | None = None, row: int | None = None, problem: str = ""
    ) -> PassFormatError:
        """The error of ``problem`` at ``table`` (a table name or ``pass.toml``), ``column``
        (or key) and ``row`` (0-based data row), each left out when ``None``."""
        where = [table if table.endswith(".toml") else f"table {table}"]
        if column is not None:
            where.append(f"{'key' if table.endswith('.toml') else 'column'} {column}")
        if row is not None:
            where.append(f"row {row}")
        return cls(f"{', '.join(where)}: {problem}")
