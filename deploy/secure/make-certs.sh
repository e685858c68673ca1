#!/bin/sh
# make-certs.sh DIR IDENTITY...: a CA (DIR/ca.pem, DIR/ca.key) if DIR has none, and for each
# IDENTITY without one a key and a certificate signed by it (DIR/IDENTITY.pem, DIR/IDENTITY.key):
# CN = IDENTITY (what the router's access control matches), SAN = 127.0.0.1 and localhost
# (plus FEDTRACK_CERT_SAN, e.g. "IP:10.47.0.1,DNS:host-a"), valid FEDTRACK_CERT_DAYS days (365).
set -eu
if [ $# -lt 2 ]; then
    echo "usage: $0 DIR IDENTITY..." >&2
    exit 2
fi
command -v openssl >/dev/null 2>&1 || { echo "$0: openssl not found" >&2; exit 2; }
dir=$1
shift
days=${FEDTRACK_CERT_DAYS:-365}
san="IP:127.0.0.1,DNS:localhost${FEDTRACK_CERT_SAN:+,$FEDTRACK_CERT_SAN}"
mkdir -p "$dir"
umask 077
if [ ! -f "$dir/ca.pem" ]; then
    openssl req -x509 -newkey rsa:2048 -nodes -keyout "$dir/ca.key" -out "$dir/ca.pem" -days "$days" \
        -subj "/CN=fedtrack-ca" -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
    echo "made CA $dir/ca.pem"
fi
for id in "$@"; do
    case $id in
        *[!A-Za-z0-9._-]*|'') echo "$0: bad identity '$id' (letters, digits, . _ -)" >&2; exit 2 ;;
    esac
    [ -f "$dir/$id.pem" ] && continue
    ext=$(mktemp)
    printf 'subjectAltName=%s\nbasicConstraints=CA:FALSE\nkeyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" >"$ext"
    openssl req -newkey rsa:2048 -nodes -keyout "$dir/$id.key" -out "$dir/$id.csr" -subj "/CN=$id" 2>/dev/null
    openssl x509 -req -in "$dir/$id.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" -CAcreateserial \
        -out "$dir/$id.pem" -days "$days" -extfile "$ext" 2>/dev/null
    rm -f "$dir/$id.csr" "$ext"
    echo "made $dir/$id.pem (CN=$id)"
done
