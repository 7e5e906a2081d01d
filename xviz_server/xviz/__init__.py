"""The XVIZ face: its protocol state machine (:mod:`.session`) and the asyncio side that carries it out
(:mod:`.connection`), as :mod:`xviz_server.foxglove` holds the Foxglove face's."""
