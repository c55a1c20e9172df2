"""Running madp's command line (:mod:`madp.cli`): how what happened becomes what the user sees.

- A user's mistake is one line ``madp: error: …`` on stderr, exit status 2: a bad flag or value
  (click's checks, typer's ranges), a :class:`madp.errors.MadpError` (a
  :class:`~madp.errors.SettingError` names the flag that set the value, a file's error names the
  file) or an ``OSError`` (a file that cannot be read or written; it names the file). ``MADP_DEBUG=1``
  raises it instead, with its traceback.
- Anything else is a bug in madp: the traceback, then one line asking for a report, exit status 1.
- A group run without a command prints its help; Ctrl-C prints ``madp: interrupted`` (status 130).
"""

from __future__ import annotations

import os
import sys
import traceback
from typing import List

import typer

from madp.errors import MadpError, SettingError

#: Settings whose flag is not their name with dashes.
RENAMED = {"num_samples": "--n", "num_workers": "--workers"}


def _click():
    """click as typer runs it (recent typer vendors it as ``typer._click``)."""
    import typer.core

    return getattr(typer.core, "_click", None) or __import__("click")


def flag(app: typer.Typer, setting: str) -> str:
    """The flag of ``app`` that sets ``setting`` (the library's name; ``a/b`` for several), or the name itself."""
    flags: dict[str, str] = {}
    commands = [typer.main.get_command(app)]
    while commands:
        cmd = commands.pop()
        commands += getattr(cmd, "commands", {}).values()
        flags.update({p.name: p.opts[0] for p in cmd.params if p.opts[0].startswith("--")})  # options, not arguments
    return "/".join(RENAMED.get(s) or flags.get(s, s) for s in setting.split("/"))


def user_message(app: typer.Typer, e: BaseException) -> str:
    """The one line a user's mistake prints: a setting's error names its flag."""
    msg = str(e) or type(e).__name__
    if isinstance(e, SettingError) and msg.startswith(e.setting):
        msg = flag(app, e.setting) + msg[len(e.setting):]
    return " ".join(msg.splitlines()[0].split())


#: ``--ray`` of datagen and eval; given alone, main() supplies ``local`` (madp.io.ray_backend.RAY_LOCAL).
RAY_HELP = ("Run the tasks on Ray: alone, a Ray started on this machine; 'auto': the cluster running here "
            "(ray start); HOST:PORT or ray://HOST:10001: that cluster. The output directory must be on a "
            "filesystem every node sees. Never changes the results. Needs madp[ray].")


def ray_option(help: str = RAY_HELP):
    return typer.Option(None, "--ray", metavar="[ADDRESS]", help=help)


def optional_ray_value(args: List[str]) -> List[str]:
    """``--ray`` followed by nothing or by another option means ``--ray local`` (click has no options
    with an optional value)."""
    from madp.io.ray_backend import RAY_LOCAL

    out = list(args)
    for i, a in enumerate(out):
        if a == "--":
            break
        if a == "--ray" and (i + 1 == len(out) or out[i + 1].startswith("-")):
            out.insert(i + 1, RAY_LOCAL)
            break
    return out


def run(app: typer.Typer, args: List[str]) -> None:
    """Run ``app`` on ``args`` and exit (see the module docstring)."""
    cx = _click()
    debug = bool(os.environ.get("MADP_DEBUG"))
    try:
        rv = app(args=optional_ray_value(args), prog_name="madp", standalone_mode=False)
    except getattr(cx.exceptions, "NoArgsIsHelpError", ()) as e:
        e.show()
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        rv = 130
    except (cx.exceptions.ClickException, typer.Abort, MadpError, OSError) as e:
        if debug:
            raise
        if isinstance(e, typer.Abort):  # typer's translation of an EOFError (a file that ends early)
            line = f"unexpected end of input ({type(e.__cause__).__name__ if e.__cause__ else 'aborted'})"
        else:
            line = e.format_message() if isinstance(e, cx.exceptions.ClickException) else user_message(app, e)
        sys.stderr.write(f"madp: error: {' '.join(line.split())}\n")
        sys.exit(2)
    except Exception:
        traceback.print_exc()
        sys.stderr.write("madp: internal error: this is a bug in madp, not a mistake in the command; please report "
                         "it with the command line and the traceback above\n")
        sys.exit(1)
    if rv == 130:  # typer's translation of KeyboardInterrupt
        sys.stderr.write("madp: interrupted\n")
    if isinstance(rv, int) and rv:
        sys.exit(rv)
