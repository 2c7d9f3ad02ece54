"""`motiongen serve`: the live web page (docs/serve.md). Builds the app from the keys
(ServeConfig, motiongen/serve/serve_config.py, through configs/serve.yaml), prints the URL and
serves until Ctrl-C."""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from motiongen.commands.hydra_app import hydra_command
from motiongen.errors import ConfigError
from motiongen.serve.launch import build_app
from motiongen.serve.serve_config import LOOPBACK, ServeConfig
from motiongen.serve.server import make_server
from motiongen.serve.vendor import missing_assets


def run(cfg: ServeConfig) -> None:
    missing = missing_assets()
    if missing:
        raise ConfigError(f"the page's scripts are missing ({', '.join(missing[:3])}...): reinstall motiongen "
                          "with npm on the PATH (pip install -e .), which vendors them from the npm registry")
    if not cfg.ckpt:
        raise ConfigError("ckpt=PATH is required (a checkpoint written by train.py)")
    app = build_app(cfg, log=lambda m: print(m, flush=True))
    try:
        server = make_server(app, cfg.host, cfg.port)
    except OSError as e:
        raise ConfigError(f"cannot listen on {cfg.host}:{cfg.port}: {e.strerror or e}; choose another port=") from None
    if cfg.host not in LOOPBACK:
        print(f"warning: host={cfg.host} makes the page reachable from other machines; it has no login",
              file=sys.stderr, flush=True)
    host, port = server.server_address[:2]
    shown = f"[{host}]" if ":" in str(host) else host
    print(f"serving on http://{shown}:{port}/  (Ctrl-C stops)", flush=True)
    app.session.start()
    try:
        server.serve_forever()
    finally:
        server.server_close()
        app.session.stop()


def _app(cfg: DictConfig, run_dir: Path) -> None:
    run(OmegaConf.to_object(cfg))


main = hydra_command("serve", _app)


if __name__ == "__main__":
    main()
