"""The browser status page of the appliance: a small stdlib HTTP server that only reads what the
others publish (a `rig capture` session folder, a training run's RUN/live/ from recon.live.publish).

    from server import serve
    handle = serve("127.0.0.1", 8765, run_dir="runs/live", session_dir="sessions/s1")
    print(handle.url); ...; handle.stop()
"""
from server.app import DEFAULT_HOST, DEFAULT_PORT, ServerHandle, serve

__all__ = ["serve", "ServerHandle", "DEFAULT_HOST", "DEFAULT_PORT"]
