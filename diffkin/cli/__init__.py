"""The ``diffkin`` command line: demo, robot info, FK, IK, workspace maps and the viewer.

    diffkin demo [--out DIR] [--quick]
    diffkin info ROBOT_OR_FILE [--end-link L] [--base-link B]
    diffkin fk ROBOT_OR_FILE q1 ... qn | --q-file configs.npy [--format text|json|npy] [--output FILE]
    diffkin ik ROBOT_OR_FILE --pose x y z qw qx qy qz | --position x y z [--seeds N] [--q0 ...] [--all ...]
        [--avoid scene.json [--margin M] [--srdf FILE.srdf ...]]
    diffkin workspace ROBOT_OR_FILE --samples N --voxel V --out map.npz [--plot slice.png] [--capability]
    diffkin place ROBOT_OR_FILE --tasks tasks.npy --region XMIN YMIN XMAX YMAX [--map cap.npz] [--plot place.png]
        [--verify K] [--out place.npz] [--avoid scene.json [--margin M] [--srdf FILE.srdf ...]] [--view]
    diffkin view ROBOT_OR_FILE [--map map.npz] [--ik-results res.npz] [--end FRAME ...]
        [--avoid scene.json [--margin M] [--srdf FILE.srdf ...]]

``ROBOT_OR_FILE`` is a built-in robot (``iiwa7``, ``iiwa14``, ``panda``, ``ur5``, ``puma560``) or a
URDF or MJCF file (``info`` prints its tree; ``fk --frame NAME`` any frame of it; the other commands use
the chain from the root to ``--end-link``). Every computation runs in float64 (``jax_enable_x64`` is
switched on by the commands).
User errors (and a missing optional dependency) print one line ``diffkin: error: ...`` to stderr and
exit with status 2; Ctrl-C exits with status 130. Compiled programs are kept in JAX's persistent
compilation cache, as every use of the library does (``--cache-dir``, ``--no-cache``, ``DIFFKIN_CACHE_DIR``; see
:mod:`diffkin._cache`).

One module per job: ``_parser`` (options), ``_errors`` (one-line errors), ``_cache`` (compilation
cache), ``_robots`` (robots by name or file), ``_scene`` (obstacles of ``--avoid``), ``_compiled``
(jitted functions shared by commands), ``_text`` (printing), ``_plots`` (figures) and one module per
command. Nothing here imports JAX until a command runs, so ``--help`` and usage errors answer at once.
"""

from __future__ import annotations

import os
import sys

from diffkin.cli._cache import use_options
from diffkin.cli._errors import EXTRAS, CLIError, with_flags
from diffkin.cli._parser import build_parser

__all__ = ["CLIError", "build_parser", "main"]


def main(argv: list[str] | None = None) -> int:
    """Run the command line.

    Args:
        argv: the arguments (default ``sys.argv[1:]``).

    Returns:
        The exit status: 0 success, 1 a result that failed (no IK solution, failed FK check),
        2 a user error or a missing optional dependency (reported as one line on stderr), 130
        interrupted (Ctrl-C; called without ``argv``, the process exits at once with ``os._exit``).
    """
    try:
        args = build_parser().parse_args(argv)
        use_options(args.cache_dir, args.no_cache)
        return args.func(args)
    except SystemExit as e:  # --help, --version
        return e.code if isinstance(e.code, int) else 0
    except BrokenPipeError:  # output piped into head & co.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except ModuleNotFoundError as e:  # an optional dependency this command needs
        name = (e.name or "a package").split(".")[0]
        print(
            f"diffkin: error: this command needs {name}, which is not installed: "
            f"pip install 'diffkin[{EXTRAS.get(name, 'demo')}]' (or pip install {name})",
            file=sys.stderr,
        )
        return 2
    except (CLIError, ImportError, ValueError, TypeError, OSError, OverflowError) as e:
        message = " ".join(str(e).split()) or type(e).__name__
        print(f"diffkin: error: {message if isinstance(e, CLIError) else with_flags(message)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ndiffkin: interrupted", file=sys.stderr, flush=True)
        if argv is None:  # the program, not a test: JAX's threads may crash a normal exit (status 139)
            sys.stdout.flush()
            os._exit(130)
        return 130
