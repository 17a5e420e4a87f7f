"""``stereod run``: the daemon, from a configuration file."""

from __future__ import annotations

import argparse
import faulthandler
import json
import logging

from stereod.cli.common import (
    EPILOG_KEYS,
    add_driver,
    add_pipeline,
    add_rate,
    add_wait_subscriber,
    load_checked,
    pipeline_overrides,
    run_daemon,
    setup_logging,
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "run",
        help="run the daemon from a config file",
        description="Run the daemon with the driver, rig, detector and Zenoh settings of a TOML "
        "config file. Environment variables STEREOD_<SECTION>__<FIELD> override the file, flags "
        "override both. Exits 78 on a bad configuration, 66 on a missing one.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_driver(p)
    add_rate(p, "playback speed for file drivers: 1 real time, 0 as fast as possible")
    add_wait_subscriber(p, "capturing")
    p.add_argument(
        "--check",
        action="store_true",
        help="validate the configuration (driver options included), print it as JSON and exit",
    )
    add_pipeline(p)
    p.set_defaults(func=run, reloads_on_sighup=True)  # its handler comes with the daemon


def run(a: argparse.Namespace) -> int:
    from stereod.daemon.daemon import Daemon
    from stereod.files.config_input import DEFAULT_CONFIG_PATH

    ov = pipeline_overrides(a)
    if a.driver:
        ov["driver"] = {"name": a.driver}
    path = a.config
    if path is None and DEFAULT_CONFIG_PATH.exists():
        path = DEFAULT_CONFIG_PATH
    cfg, driver = load_checked(path, ov)
    setup_logging(cfg.daemon.log_level)
    if a.check:
        shown = cfg.model_dump(mode="json")
        read = driver.options_read()
        if read is not None:  # as the driver read them: "15" from the environment is 15
            shown["driver"]["options"] = read
        # the level the run logs at: STEREOD_LOG_LEVEL (no field) overrides the configured one
        shown["daemon"]["log_level"] = logging.getLevelName(logging.getLogger().level)
        print(json.dumps(shown, indent=2))
        return 0
    # Each thread's Python stack to stderr (the journal) should the process die by a signal
    # such as the SIGABRT of systemd's watchdog: where a stuck thread was stuck.
    faulthandler.enable()
    daemon = Daemon(
        cfg,
        driver,
        rate=a.rate,
        wait_subscriber_s=a.wait_subscriber,
        reload_config=lambda: load_checked(path, ov)[0],
    )
    return run_daemon(daemon, quiet=None, problems_fail=False)
