"""The options of ``executor=serial`` and ``executor=dask``, typed and checked once.

One frozen dataclass per executor (:func:`framework.options.option` fields: the default and the
description of each option in one place; ``framework/conf/executor/<name>.yaml`` is generated from
them by :mod:`framework.method_yaml`). :func:`executor_options` turns the composed ``executor``
group into one; :func:`framework.executor.make_executor` takes it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

from framework.errors import ConfigError
from framework.options import Check, build, nullable, number, option

#: the schemes of a scheduler address the run accepts (distributed's TCP and TLS comms)
ADDRESS_SCHEMES = ("tcp", "tls")


def check_address(key: str, address):
    """``executor.address``: ``null`` or ``tcp://host:port`` (``tls://`` too), port 1-65535;
    returned as text.

    Checked before anything starts: distributed raises ``ValueError: missing port number`` or
    an unknown-scheme error only once the run is under way.

    Raises
    ------
    framework.errors.ConfigError
        Naming the address and the form to write.
    """
    text = str(address)
    form = f"write tcp://host:port (the scheduler's address, port 8786 by default), or {key}=null"
    scheme, sep, rest = text.partition("://")
    if not sep:
        raise ConfigError(f"{key}={text} is not a scheduler address: {form}")
    if scheme not in ADDRESS_SCHEMES:
        raise ConfigError(f"{key}={text}: the scheme {scheme}:// is not one a Dask scheduler "
                          f"listens on ({', '.join(s + '://' for s in ADDRESS_SCHEMES)}): {form}")
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"{key}={text} lacks a host and a port number (1-65535): {form}")
    return text


@dataclass(frozen=True)
class SerialOptions:
    """Render views and tiles in this process (the default)."""

    name = "serial"


@dataclass(frozen=True)
class DaskOptions:
    """Render views in Dask workers: a local cluster started for the run, or the scheduler at
    ``address``, whose workers must import this repository (same code, same Python environment)."""

    name = "dask"
    address: str | None = option(
        "`null` starts a `distributed.LocalCluster` of `n_workers` processes for the run and closes it "
        "afterwards; `tcp://host:port` (or `tls://`) joins that scheduler",
        nullable(Check("`tcp://host:port`", check_address)), default=None)
    n_workers: int = option("worker processes of the local cluster (a scheduler's own workers otherwise)",
                            number(1, integer=True), default=2)
    threads_per_worker: int = option("Dr.Jit threads per worker, so the workers do not oversubscribe the cores",
                                     number(1, integer=True), default=1)
    connect_timeout_s: float = option(
        "seconds to wait for the scheduler at `address` before giving up (distributed's own 30 s made "
        "a wrong address look like a hang)", number(0.0, lo_open=True), default=5.0)


#: ``executor=<name>`` -> its options dataclass
EXECUTORS = {"serial": SerialOptions, "dask": DaskOptions}


def executor_options(cfg) -> SerialOptions | DaskOptions:
    """The checked options of the ``executor`` config group ``cfg`` (None or missing: serial);
    already built options are returned as they are.

    Raises
    ------
    framework.errors.ConfigError
        For an unknown ``executor.name``, an unknown key or the first bad value, in one line.
    """
    if isinstance(cfg, (SerialOptions, DaskOptions)):
        return cfg
    if cfg is None:
        return SerialOptions()
    if not isinstance(cfg, Mapping):
        raise ConfigError(f"executor={cfg} is not a mapping: choose executor=serial or executor=dask")
    name = str(cfg.get("name", "serial"))
    if name not in EXECUTORS:
        raise ConfigError(f"executor={name} is not an executor: use {' or '.join(EXECUTORS)}")
    cls = EXECUTORS[name]

    def unknown(key: str) -> str:
        own = ", ".join(f.name for f in fields(cls)) or "none"
        having = [n for n, c in EXECUTORS.items() if key.split(".")[-1] in {f.name for f in fields(c)}]
        where = f"; executor={having[0]} has it" if having else ""
        return f"{key} is not an option of executor={name} (its options: {own}){where}: drop it, or choose the executor"
    return build(cls, cfg, section="executor", ignore=("name",), unknown_hint=unknown)
