"""The browser status page of the appliance: a small stdlib HTTP server that only reads what the
others publish (a `rig capture` session folder, a training run's RUN/live/ from recon.live.publish,
a `recon batch` folder's batch.json and its jobs' runs).

    from server import serve
    handle = serve("127.0.0.1", 8765, run_dir="runs/live", session_dir="sessions/s1")
    print(handle.url); ...; handle.stop()
    handle = serve("127.0.0.1", 8765, batch_dir="runs/b1")     # jobs' table; job N's page at /job/N/
"""
from server.app import DEFAULT_HOST, DEFAULT_PORT, ServerHandle, serve

__all__ = ["serve", "ServerHandle", "DEFAULT_HOST", "DEFAULT_PORT"]
