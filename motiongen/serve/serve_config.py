"""The keys of `motiongen serve`: the checkpoint, scene and sampler keys of `sample`
(SceneRouteKeys, SamplerSettings, the episode loop), where the server listens, and how far
generation runs ahead of playback. docs/serve.md explains them."""

from __future__ import annotations

from dataclasses import dataclass, field

from motiongen.checks import require_range
from motiongen.errors import ConfigError
from motiongen.sampling.sample_config import SceneRouteKeys, check_loop, check_sampler_settings, check_scene_route_keys
from motiongen.sampling.settings import LoopConfig, SamplerSettings

LOOPBACK = ("127.0.0.1", "localhost", "::1")


@dataclass
class ServeConfig(SamplerSettings, SceneRouteKeys):
    # One torch thread for the generation: on 2 cores the other serves the requests, the clock
    # and the Python half of each episode; two threads made each episode slower and the click
    # latency longer (docs/results.md#live-control). 0 = torch's default (one per core).
    threads: int = 1
    seed: int = 0
    host: str = "127.0.0.1"        # the interface to listen on; anything but loopback is reachable from other machines
    port: int = 8000               # 0: a free port
    lead_s: float = 1.5            # seconds of motion generated ahead of playback
    max_pending: int = 100         # goals waiting at most
    loop: LoopConfig = field(default_factory=LoopConfig)   # the episodes (its clean-up keys do not apply live)

    def __post_init__(self):
        super().__post_init__()
        check_sampler_settings(self)
        check_scene_route_keys(self)
        require_range("seed", self.seed, 0, integer=True)
        require_range("port", self.port, 0, 65535, integer=True)
        require_range("lead_s", self.lead_s, 0.1, 60)
        require_range("max_pending", self.max_pending, 1, 10000, integer=True)
        if not self.host or any(c.isspace() for c in self.host):
            raise ConfigError(f"host: expected an address such as 127.0.0.1, got {self.host!r}")
        check_loop(self.loop)
