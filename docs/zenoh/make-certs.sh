#!/usr/bin/env sh
# A throw-away CA and a certificate for "localhost" (and 127.0.0.1), for trying Zenoh's TLS on one machine.
# Usage: docs/zenoh/make-certs.sh DIR   (writes DIR/ca.pem, DIR/cert.pem, DIR/key.pem)
set -eu
dir="${1:-certs}"
mkdir -p "$dir"
cd "$dir"
openssl req -x509 -newkey rsa:2048 -nodes -keyout ca.key -out ca.pem -days 30 -subj "/CN=quadsitl test CA" 2>/dev/null
openssl req -newkey rsa:2048 -nodes -keyout key.pem -out server.csr -subj "/CN=localhost" 2>/dev/null
printf "subjectAltName=DNS:localhost,IP:127.0.0.1\n" > ext.cnf
openssl x509 -req -in server.csr -CA ca.pem -CAkey ca.key -CAcreateserial -out cert.pem -days 30 -extfile ext.cnf 2>/dev/null
rm -f server.csr ext.cnf ca.srl
echo "wrote $dir/ca.pem, $dir/cert.pem, $dir/key.pem"
