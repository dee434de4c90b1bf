"""The command-line pieces the developer scripts of docs/scripts share.

Not a script: the scripts import it (``python docs/scripts/X.py`` puts docs/scripts first on
``sys.path``). Each script builds its parser with :func:`script_parser`, takes the folder of
the project's real recordings with :func:`add_real_data` (or reads it from
``$NAPARI_SYMBAC_REAL_DATA`` with :func:`real_data_from_environment`) and turns a folder that
is not there into a usage error with :func:`checked_real_data`; a script that takes only that
folder reads its whole command line with :func:`parse_real_data`.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Literal

ROOT = Path(__file__).resolve().parents[2]
#: The folder of the project's real recordings, beside the repository (its README lists them).
REAL_DATA = ROOT.parent / "shared" / "data" / "real"
#: The environment variable some scripts read that folder from instead.
REAL_DATA_VARIABLE = "NAPARI_SYMBAC_REAL_DATA"

#: How the user points a script at the real recordings, by where its path came from.
_REMEDIES = {
    "argument": ": pass that folder as REAL_DATA_DIR",
    "environment": f": set ${REAL_DATA_VARIABLE} to that folder",
    "repository": " beside the repository",
}


def script_parser(doc: str | None, usage: str | None = None) -> argparse.ArgumentParser:
    """A script's parser, its ``--help`` the script's docstring as written.

    Parameters
    ----------
    doc
        The script's ``__doc__``.
    usage
        The usage line, where argparse's own would mislead; by default argparse's.

    Returns
    -------
    argparse.ArgumentParser
        The parser, without arguments yet.
    """
    return argparse.ArgumentParser(
        usage=usage, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


def add_real_data(
    parser: argparse.ArgumentParser,
    *,
    required: bool = False,
    help: str = "the folder of the project's real recordings",
) -> None:
    """Add the ``REAL_DATA_DIR`` positional, as ``real``.

    Parameters
    ----------
    parser
        The script's parser.
    required
        Whether it must be given; if not it defaults to :data:`REAL_DATA`.
    help
        Its help line; the default is named after it when it is optional.
    """
    if required:
        parser.add_argument("real", type=Path, metavar="REAL_DATA_DIR", help=help)
    else:
        parser.add_argument(
            "real",
            nargs="?",
            type=Path,
            default=REAL_DATA,
            metavar="REAL_DATA_DIR",
            help=f"{help} (default: ../shared/data/real beside the repository)",
        )


def real_data_from_environment() -> Path:
    """The folder of the real recordings: ``$NAPARI_SYMBAC_REAL_DATA``, else :data:`REAL_DATA`.

    Returns
    -------
    Path
        The folder, not checked.
    """
    return Path(os.environ.get(REAL_DATA_VARIABLE, REAL_DATA))


def checked_real_data(
    parser: argparse.ArgumentParser,
    path: Path,
    holds: str,
    *,
    given: Literal["argument", "environment", "repository"] = "argument",
    file: bool = False,
) -> Path:
    """``path`` if it is there, else a usage error (exit 2) naming it.

    Parameters
    ----------
    parser
        The script's parser, which reports the error.
    path
        The real-recordings folder, a folder in it, or (``file``) one recording.
    holds
        What the script reads from there, for the message.
    given
        Where ``path`` came from: the ``REAL_DATA_DIR`` argument, the environment
        (:func:`real_data_from_environment`) or the fixed place beside the repository; the
        message tells the user how to point the script elsewhere accordingly.
    file
        Whether ``path`` is a file rather than a folder.

    Returns
    -------
    Path
        ``path``.
    """
    if not (path.is_file() if file else path.is_dir()):
        parser.error(
            f"{path} not found: this script reads {holds} from the folder of the project's "
            f"real recordings{_REMEDIES[given]} (its README lists them)"
        )
    return path


def parse_real_data(doc: str | None, holds: str, argv: list[str] | None = None) -> Path:
    """The whole command line of a script that takes only ``[REAL_DATA_DIR]``.

    Parameters
    ----------
    doc
        The script's ``__doc__``, for ``--help``.
    holds
        What the script reads from the folder, for the message if it is not there.
    argv
        The arguments; by default ``sys.argv[1:]``.

    Returns
    -------
    Path
        The folder of the real recordings, there (else a usage error, exit 2).
    """
    parser = script_parser(doc)
    add_real_data(parser)
    return checked_real_data(parser, parser.parse_args(argv).real, holds)
