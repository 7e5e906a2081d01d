#!/bin/sh
# Exit 0 when the server in this container answers /healthz.
exec python3 -c "import os, sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('XVIZ_PORT', '3000'), timeout=3).read() == b'ok\n' else 1)"
