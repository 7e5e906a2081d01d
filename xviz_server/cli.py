"""The ``xviz-server`` command."""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import subprocess
import sys
import types
import typing
from collections.abc import Callable, Coroutine, Sequence
from pathlib import Path
from typing import Any

import orjson
import pydantic

from .exceptions import ConfigError
from .logfmt import configure_logging, redact_password
from .settings import SECRETS, Settings, load_settings
from .version import __version__

__all__ = ["main"]


def _run_async(coroutine: Coroutine[Any, Any, Any]) -> Any:
    """Run on uvloop where it is installed, else on the standard event loop."""
    try:
        import uvloop
    except ImportError:
        return asyncio.run(coroutine)
    return uvloop.run(coroutine)


def _option_type(annotation: Any) -> Callable[[str], Any]:
    """The argparse type of a settings field: the non-``None`` member of an optional."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        (annotation,) = [arg for arg in typing.get_args(annotation) if arg is not type(None)]
    return annotation


def _add_settings_options(parser: argparse.ArgumentParser) -> None:
    """``--config`` and one option per :class:`Settings` field, named like it (``--cache-mb``)."""
    parser.add_argument("--config", type=Path, metavar="FILE", help="TOML file of settings (env XVIZ_CONFIG)")
    for name, field in Settings.model_fields.items():
        flag = "--" + name.replace("_", "-")
        env = f"XVIZ_{name.upper()}"
        if field.annotation is bool:
            parser.add_argument(
                flag, action=argparse.BooleanOptionalAction, default=None, help=f"{field.description} (env {env})"
            )
        elif typing.get_origin(field.annotation) is typing.Literal:
            choices = typing.get_args(field.annotation)
            parser.add_argument(
                flag, choices=choices, default=None, help=f"{field.description} (env {env}; default {field.default})"
            )
        elif typing.get_origin(field.annotation) is list:
            metavar = "KIND:PATH" if name == "dataset" else name.split("_")[-1].upper().removesuffix("S")
            parser.add_argument(
                flag, action="append", default=None, metavar=metavar, help=f"{field.description} (env {env})"
            )
        else:
            default = "" if field.default is None else f"; default {field.default}"
            parser.add_argument(
                flag,
                type=_option_type(field.annotation),
                default=None,
                metavar=name.split("_")[-1].upper(),
                help=f"{field.description} (env {env}{default})",
            )


def _settings(args: argparse.Namespace) -> Settings:
    given = {name: getattr(args, name) for name in Settings.model_fields if getattr(args, name) is not None}
    config = args.config or os.environ.get("XVIZ_CONFIG")
    return load_settings(Path(config) if config else None, **given)


def _settings_or_report(args: argparse.Namespace, command: str) -> Settings | None:
    """The effective settings, or ``None`` after saying on standard error what is wrong."""
    try:
        return _settings(args)
    except FileNotFoundError as exc:
        print(f"xviz-server {command}: {exc}", file=sys.stderr)
    except pydantic.ValidationError as exc:
        for error in exc.errors():
            if error["loc"]:
                option = "--" + "-".join(str(part) for part in error["loc"]).replace("_", "-")
                print(f"xviz-server {command}: {option}: {error['msg']}", file=sys.stderr)
            else:  # a ConfigError about several settings: its message names them
                print(f"xviz-server {command}: {error['ctx']['error']}", file=sys.stderr)
    return None


def _config(args: argparse.Namespace) -> int:
    settings = _settings_or_report(args, "config")
    if settings is None:
        return 2
    for name, value in settings.model_dump(mode="json").items():
        if value is None:
            print(f"# {name} is not set")
        elif name in SECRETS:
            print(f"# {name} is set (not shown)")
        elif name == "broker":
            print(f"{name} = {_toml(redact_password(value))}")
        else:
            print(f"{name} = {_toml(value)}")
    return 0


def _healthcheck(args: argparse.Namespace) -> int:
    """Exit status 0 when healthy, else 1 (Docker reserves 2), for wrong settings too."""
    from .healthcheck import ServeProcess, health_url, unhealthy_reason

    if args.pid is not None:
        try:
            process = ServeProcess(args.pid)
        except ConfigError as exc:
            print(f"xviz-server healthcheck: {exc}", file=sys.stderr)
            return 1
        command = [
            sys.executable,
            "-m",
            "xviz_server",
            "healthcheck",
            "--timeout",
            str(args.timeout),
            *process.arguments,
        ]
        try:
            status = subprocess.run(command, env=process.environ, cwd=process.cwd, timeout=args.timeout + 30).returncode
            return 0 if status == 0 else 1
        except subprocess.TimeoutExpired:
            print("xviz-server healthcheck: the check itself timed out", file=sys.stderr)
            return 1
    settings = _settings_or_report(args, "healthcheck")
    if settings is None:
        return 1
    url = health_url(settings)
    reason = unhealthy_reason(url, args.timeout)
    if reason is not None:
        print(f"unhealthy: {reason}", file=sys.stderr)
        return 1
    print(f"healthy: {url}")
    return 0


def _toml(value: Any) -> str:
    """A setting's value as TOML (settings are strings, numbers, booleans and lists of strings)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(_toml(item) for item in value) + "]"
    if isinstance(value, str):
        return orjson.dumps(value).decode()
    return str(value)


def _serve(args: argparse.Namespace) -> int:
    from .server import run
    from .store import is_store_url

    settings = _settings_or_report(args, "serve")
    if settings is None:
        return 2
    configure_logging(settings.log_format)
    if not settings.data_dir and not settings.dataset:
        settings = settings.model_copy(update={"dataset": ["demo"]})
        logging.getLogger("xviz_server").info("no --data-dir: serving the built-in demo log as 'demo'")
    for directory in settings.data_dir:
        if not is_store_url(directory) and not Path(directory).is_dir():
            print(
                f"xviz-server serve: --data-dir {directory} is not a directory{_serve_file_hint(directory)}",
                file=sys.stderr,
            )
            return 2
    try:
        _run_async(run(settings))
    except ValueError as exc:  # a --dataset that is not KIND:PATH, a TLS file that cannot serve (ConfigError)
        print(f"xviz-server serve: {exc}", file=sys.stderr)
        return 2
    return 0


def _serve_file_hint(path: str) -> str:
    """For a ``--data-dir`` that is a dataset's file (``drive.bag``): how to serve it, after a colon; else nothing."""
    from .datasets import FILE_KINDS, detect

    file = Path(path)
    kind = (detect(file) or FILE_KINDS.get(file.suffix)) if file.is_file() else None
    if kind is None:
        return ""
    return f": to serve this file alone, give --dataset {kind}:{path} (--data-dir takes the folder that holds it)"


def _validate(args: argparse.Namespace) -> int:
    from .validate import check_paths

    report = check_paths(args.paths)
    print(orjson.dumps(report.as_dict(), option=orjson.OPT_INDENT_2).decode() if args.json else report.render())
    return 0 if report.ok else 1


def _probe(args: argparse.Namespace) -> int:
    from .codec import Format
    from .probe import Instant, probe

    def instant(text: str | None) -> Instant | None:
        return None if text is None else Instant.parse(text)

    try:
        report = _run_async(
            probe(
                args.url,
                fmt=None if args.format is None else Format(args.format.upper()),
                start=instant(args.start),
                end=instant(args.end),
                streams=args.streams,
                point_in_time=instant(args.point_in_time),
                validate=args.validate,
                timeout=args.timeout,
            )
        )
    except ValueError as exc:  # a URL that is not ws://..., a time that is not a time
        print(f"xviz-server probe: {exc}", file=sys.stderr)
        return 2
    print(orjson.dumps(report.as_dict(), option=orjson.OPT_INDENT_2).decode() if args.json else report.render())
    return 0 if report.clean else 1


def _convert(args: argparse.Namespace) -> int:
    from .codec import Format
    from .convert import convert
    from .datasets import dataset_options
    from .exceptions import XVIZError

    options: dict[str, Any] = {"image_max_width": args.image_max_width}
    if args.config is not None:
        if "config" not in dataset_options(args.kind):
            print(f"xviz-server convert: --config is for rosbag datasets, not {args.kind}", file=sys.stderr)
            return 2
        options["config"] = str(args.config)
    try:
        convert(
            args.kind,
            args.source,
            args.output,
            fmt=Format.JSON if args.format == "json" else Format.BINARY,
            frames=args.frames,
            options=options,
            processes=args.processes,
        )
    except (ValueError, XVIZError) as exc:
        print(f"xviz-server convert: {exc}", file=sys.stderr)
        return 1 if isinstance(exc, XVIZError) else 2
    except OSError as exc:  # a source that cannot be read, an output that cannot be written (a read-only store)
        print(f"xviz-server convert: {exc.filename or args.output}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("\nxviz-server convert: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    return 0


def _inspect(args: argparse.Namespace) -> int:
    from .datasets.ros.inspect import inspect_bag, render
    from .exceptions import DatasetError

    try:
        report = inspect_bag(args.path, None if args.config is None else str(args.config))
    except DatasetError as exc:
        print(f"xviz-server inspect: {exc}", file=sys.stderr)
        return 1
    print(orjson.dumps(report, option=orjson.OPT_INDENT_2).decode() if args.json else render(report))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="xviz-server",
        description="Serve XVIZ v2 logs, raw datasets and live feeds to streetscape.gl and scripted clients.",
    )
    parser.add_argument("--version", action="version", version=f"xviz-server {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")

    serve = commands.add_parser(
        "serve",
        help="serve logs over WebSocket",
        description="Serve the XVIZ logs found under --data-dir (or the built-in demo log) to "
        "streetscape.gl and scripted clients. Every option can also be set by its environment variable or in "
        "the TOML file given by --config; flags win over the environment, which wins over the file.",
    )
    _add_settings_options(serve)
    serve.set_defaults(run=_serve)

    config = commands.add_parser(
        "config",
        help="print the effective configuration",
        description="Print the settings `serve` would run with, from flags, XVIZ_* variables and --config, as TOML.",
    )
    _add_settings_options(config)
    config.set_defaults(run=_config)

    healthcheck = commands.add_parser(
        "healthcheck",
        help="ask a running server's /healthz (for container health checks)",
        description="Ask GET /healthz of the server that `serve` runs with the same settings (flags, XVIZ_* "
        "variables, --config), over https when --certfile is set. Exit status 0 when it answers 200, 1 otherwise.",
    )
    _add_settings_options(healthcheck)
    healthcheck.add_argument(
        "--timeout", type=float, default=3.0, metavar="S", help="give up after S seconds (default 3)"
    )
    healthcheck.add_argument(
        "--pid",
        type=int,
        metavar="PID",
        help="check the `xviz-server serve` running as process PID, with its own command line and environment "
        "(read from /proc); in the Docker image, --pid 1",
    )
    healthcheck.set_defaults(run=_healthcheck)

    validate = commands.add_parser(
        "validate",
        help="check XVIZ files and log directories against the schema",
        description="Check message files (GLB or JSON) and log directories against the XVIZ v2 schema and the "
        "reference log layout (metadata, frames, index). Exit status 0 when everything is valid, 1 otherwise.",
    )
    validate.add_argument(
        "paths", nargs="+", type=Path, metavar="PATH", help="a file, a log directory, or a directory of logs"
    )
    validate.add_argument("--json", action="store_true", help="print the report as JSON")
    validate.set_defaults(run=_validate)

    probe = commands.add_parser(
        "probe",
        help="run a scripted session against a server (CI smoke test)",
        description="Connect like streetscape.gl, request a range (and an instant), check every message and "
        "print a summary. Times are seconds, or +seconds from the log's start. Exit status 0 when the session "
        "was clean, 1 when something was wrong (an xviz/error, a bad message or frame, a timeout...), 2 for a "
        "usage error.",
    )
    probe.add_argument("url", help="ws://HOST:PORT/?log=NAME")
    probe.add_argument("--format", choices=["json", "binary"], type=str.lower, help="message_format to ask for")
    probe.add_argument("--start", metavar="T", help="start of the range (default: the log's start)")
    probe.add_argument("--end", metavar="T", help="end of the range (default: the log's end)")
    probe.add_argument("--streams", nargs="+", metavar="STREAM", help="ask for these streams only")
    probe.add_argument("--point-in-time", metavar="T", help="also ask for the complete state at this time")
    probe.add_argument("--validate", action="store_true", help="check every message against the XVIZ schema")
    probe.add_argument("--timeout", type=float, default=30.0, metavar="S", help="give up after S seconds (default 30)")
    probe.add_argument("--json", action="store_true", help="print the summary as JSON")
    probe.set_defaults(run=_probe)

    from .datasets import DATASET_KINDS, DEFAULT_IMAGE_WIDTH

    convert = commands.add_parser(
        "convert",
        help="convert a raw dataset into a static log",
        description="Convert a raw dataset (a KITTI raw drive folder, ...) into a log in the reference layout, "
        "using every core. An interrupted conversion resumes when run again.",
    )
    convert.add_argument("kind", choices=sorted(DATASET_KINDS), help="dataset kind")
    convert.add_argument("source", type=Path, help="the dataset (e.g. a KITTI drive folder)")
    convert.add_argument("output", type=Path, help="the log directory to write")
    convert.add_argument(
        "--format", choices=["glb", "json"], type=str.lower, default="glb", help="frame format (default glb)"
    )
    convert.add_argument("--frames", metavar="A:B", help="convert frames A to B-1 only (either may be left out)")
    convert.add_argument(
        "--image-max-width",
        type=int,
        default=DEFAULT_IMAGE_WIDTH,
        metavar="W",
        help=f"scale camera images down to W pixels (default {DEFAULT_IMAGE_WIDTH})",
    )
    convert.add_argument("--processes", type=int, metavar="N", help="worker processes (default: one per core)")
    convert.add_argument(
        "--config", type=Path, metavar="FILE", help="rosbag: TOML file of the mapping (see docs/bags.md)"
    )
    convert.set_defaults(run=_convert)

    inspect = commands.add_parser(
        "inspect",
        help="list a ROS bag's topics and what they would become",
        description="Print the topics of a ROS 1 bag, ROS 2 bag folder or MCAP file: message type, count, rate, "
        "time span, and the XVIZ streams the default mapping (or --config) makes of each. Exit status 1 when the "
        "bag cannot be read.",
    )
    inspect.add_argument("path", type=Path, help="a .bag or .mcap file, or a ROS 2 bag folder")
    inspect.add_argument("--config", type=Path, metavar="FILE", help="TOML file of the mapping")
    inspect.add_argument("--json", action="store_true", help="print the report as JSON")
    inspect.set_defaults(run=_inspect)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    configure_logging(os.environ.get("XVIZ_LOG_FORMAT", "text"))
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
