#!/bin/bash
# Remote stores against the local file (docs/benchmarks.md, "Remote stores"): the same 8192^2
# store served from a file, from nginx (http://, range requests) and from s3rver (s3://), all on
# loopback, RAM cache on (256 MiB) and off. Per backing: tessera loadtest (8 viewers, flyover,
# 5 s measured) and a cold HTTP fetch of the 1024 level-0 tiles by 16 clients.
#   bench/remote_stores.sh [BUILD_DIR]     (needs nginx and tests/npm's s3rver: tools/setup.sh)
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
B=$(cd "${1:-$ROOT/build}" && pwd)
D=$(mktemp -d); trap 'rm -rf "$D"' EXIT; mkdir -p $D/www $D/s3; chmod 755 $D
$B/tessera build -q procedural:terrain:8192 -o $D/www/terrain.tsr
chmod 755 $D $D/www; chmod 644 $D/www/terrain.tsr
NP=51080; S3P=51081
cat > $D/nginx.conf <<NG
daemon off; pid $D/nginx.pid; error_log $D/nginx-error.log;
events { worker_connections 1024; }
http { access_log off; client_body_temp_path $D/body; proxy_temp_path $D/proxy; fastcgi_temp_path $D/fcgi; uwsgi_temp_path $D/uwsgi; scgi_temp_path $D/scgi;
  server { listen 127.0.0.1:$NP; root $D/www; } }
NG
nginx -c $D/nginx.conf -p $D & NGPID=$!
$ROOT/tests/npm/node_modules/.bin/s3rver -d $D/s3 -a 127.0.0.1 -p $S3P --configure-bucket tiles -s & S3PID=$!
sleep 2
cd $ROOT/tests && python3 -c "
import remote_store_test as t
t.sigv4_put('http://127.0.0.1:$S3P','tiles','terrain.tsr',open('$D/www/terrain.tsr','rb').read())"
export AWS_ACCESS_KEY_ID=S3RVER AWS_SECRET_ACCESS_KEY=S3RVER AWS_ENDPOINT_URL=http://127.0.0.1:$S3P
for cache in 256MiB 0; do
 for store in $D/www/terrain.tsr http://127.0.0.1:$NP/terrain.tsr s3://tiles/terrain.tsr; do
  $B/tessera-server serve --store $store --grpc 127.0.0.1:51090 --http 127.0.0.1:51091 --cache-size $cache --log-format text 2> $D/srv.log & SP=$!
  sleep 1.5
  $B/tessera loadtest --server 127.0.0.1:51090 --store terrain --viewers 8 --duration 5 --warmup 1 --quiet --json $D/r.json > /dev/null
  python3 -c "
import json; r=json.load(open('$D/r.json'))['runs'][0]; l=r['latency_ms']
print('cache $cache'.ljust(14), '$store'.split('/')[0].ljust(6) if '$store'.startswith(('http','s3')) else 'file  ', 'tiles/s %8.1f  p50 %7.2f ms  p99 %7.2f ms  fallback %.3f%%  failed %d' % (r['tiles_per_s'] if 'tiles_per_s' in r else r['tiles']/5.0, l['p50'], l['p99'], 100*r['fallback'], r['failed']))"
  echo -n "   cold HTTP fetch of 1024 level-0 tiles, 16 clients: "; python3 $ROOT/bench/tile_fetch.py 51091
  curl -s 127.0.0.1:51091/metrics | grep -E "^tessera_store_(tiles_read|reads)_total|^tessera_remote_requests " | tr '\n' ' '; echo
  kill $SP; wait $SP 2>/dev/null || true
 done
done
kill $NGPID $S3PID
