#!/usr/bin/env bash
# Write a private CA and one certificate for a Dask cluster's scheduler, workers and clients.
#
#   cluster/local/make-certs.sh DIR [--hosts "127.0.0.1,localhost,node01"] [--days 30] [--force]
#
# DIR gets ca.pem (the CA certificate), cert.pem and key.pem (the certificate and key
# every process presents: dask scheduler/worker --tls-ca-file DIR/ca.pem --tls-cert
# DIR/cert.pem --tls-key DIR/key.pem; mercury-dem run takes the same three flags).
# The CA key is deleted once the certificate is signed, so nothing else can be signed
# with it. DIR is created mode 700 and the key is mode 600: keep it on a file system
# only you (and your batch jobs) can read.
# Dask checks the chain, not host names, so --hosts is informational (subjectAltName);
# list the machines anyway so other TLS clients can verify them.
set -euo pipefail

usage() { sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit "${1:-2}"; }

dir=""; hosts="127.0.0.1,localhost"; days=30; force=0
while [ $# -gt 0 ]; do
  case "$1" in
    --hosts) hosts="$2"; shift 2 ;;
    --days) days="$2"; shift 2 ;;
    --force) force=1; shift ;;
    -h|--help) usage 0 ;;
    -*) echo "make-certs.sh: unknown option $1" >&2; usage ;;
    *) [ -z "$dir" ] || usage; dir="$1"; shift ;;
  esac
done
[ -n "$dir" ] || usage
command -v openssl >/dev/null || { echo "make-certs.sh: openssl is not installed (apt-get install openssl)" >&2; exit 1; }
if [ -e "$dir/key.pem" ] && [ "$force" = 0 ]; then
  echo "make-certs.sh: $dir/key.pem exists; use --force to replace the certificates" >&2; exit 1
fi

umask 077
mkdir -p "$dir"; chmod 700 "$dir"
work="$(mktemp -d "$dir/.work.XXXXXX")"
trap 'rm -rf "$work"' EXIT

san=""
IFS=',' read -ra items <<< "$hosts"
for h in "${items[@]}"; do
  h="${h// /}"; [ -n "$h" ] || continue
  if [[ "$h" =~ ^[0-9.]+$ || "$h" == *:* ]]; then san="${san:+$san,}IP:$h"; else san="${san:+$san,}DNS:$h"; fi
done

# CA: EC P-256 key, self-signed, may sign only end-entity certificates (pathlen 0).
openssl req -x509 -new -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -sha256 -days "$days" \
  -subj "/CN=mercury-dem dask CA" \
  -addext "basicConstraints=critical,CA:TRUE,pathlen:0" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  -keyout "$work/ca.key" -out "$work/ca.pem" 2>/dev/null

# One certificate for every role: Dask's peers are both TLS servers and clients.
openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -sha256 \
  -subj "/CN=mercury-dem dask" -keyout "$work/key.pem" -out "$work/req.csr" 2>/dev/null
cat > "$work/ext.cnf" <<EXT
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$san
EXT
openssl x509 -req -in "$work/req.csr" -CA "$work/ca.pem" -CAkey "$work/ca.key" -CAcreateserial \
  -days "$days" -sha256 -extfile "$work/ext.cnf" -out "$work/cert.pem" 2>/dev/null
openssl verify -CAfile "$work/ca.pem" "$work/cert.pem" >/dev/null

mv -f "$work/ca.pem" "$dir/ca.pem"; mv -f "$work/cert.pem" "$dir/cert.pem"; mv -f "$work/key.pem" "$dir/key.pem"
chmod 644 "$dir/ca.pem" "$dir/cert.pem"; chmod 600 "$dir/key.pem"
echo "wrote $dir/ca.pem $dir/cert.pem $dir/key.pem (valid $days days; hosts $san)"
