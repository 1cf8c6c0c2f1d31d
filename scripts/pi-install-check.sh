#!/usr/bin/env bash
# Follows the install in docs/raspberry-pi.md section 8 (and the config and unit lines of
# sections 9 and 10), as written, in a Debian bookworm root of another architecture under
# emulation, as a user "pi" with sudo, and says how long each step took.
#
#   sudo scripts/pi-install-check.sh arm64|armhf [ROOT_DIR]
#
# Needs root on a Debian or Ubuntu machine (debootstrap, qemu-user-static and binfmt-support
# are apt-installed if missing) and the network (Debian's mirror, PyPI; astral.sh if it is
# reachable, else Debian's pipx installs uv). Slow:
# every program in the root runs emulated, and on armhf the install compiles cffi, zstandard,
# lz4 and PyYAML; allow an hour or more. Not run by CI.
#
# Each command is first looked up in the docs or the README (`doc`): one the docs no longer say stops the
# check, so the script cannot drift from what a brewer is told to type.
set -euo pipefail

arch=${1:-}
case "$arch" in
  arm64) qemu=qemu-aarch64-static ;;
  armhf) qemu=qemu-arm-static ;;
  *) echo "usage: $0 arm64|armhf [ROOT_DIR]" >&2; exit 2 ;;
esac
[ "$(id -u)" -eq 0 ] || { echo "$0: run as root (debootstrap, mount, chroot)" >&2; exit 2; }
checkout=$(cd "$(dirname "$0")/.." && pwd)
docs="$checkout/docs/raspberry-pi.md"
root=${2:-/var/tmp/hermsd-pi-$arch}

missing=()
command -v debootstrap >/dev/null || missing+=(debootstrap)
command -v "$qemu" >/dev/null || missing+=(qemu-user-static)
[ -e /usr/sbin/update-binfmts ] || missing+=(binfmt-support)
if [ "${#missing[@]}" -gt 0 ]; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
fi
[ -d /proc/sys/fs/binfmt_misc ] && ! mountpoint -q /proc/sys/fs/binfmt_misc \
  && mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc
update-binfmts --enable >/dev/null 2>&1 || true
# sudo in the root is setuid: qemu must run it with the file's credentials (the `C` flag),
# which Debian's registration leaves out; registered again with it.
handler=/proc/sys/fs/binfmt_misc/qemu-${qemu#qemu-}
handler=${handler%-static}
if [ -e "$handler" ] && ! grep -q '^flags:.*C' "$handler"; then
  interpreter=$(sed -n 's/^interpreter //p' "$handler")
  flags=$(sed -n 's/^flags: //p' "$handler")
  offset=$(sed -n 's/^offset //p' "$handler")
  magic=$(sed -n 's/^magic //p' "$handler" | sed 's/../\\x&/g')
  mask=$(sed -n 's/^mask //p' "$handler" | sed 's/../\\x&/g')
  echo -1 >"$handler"
  printf ':%s:M:%s:%s:%s:%s:%sC' "$(basename "$handler")" "$offset" "$magic" "$mask" \
    "$interpreter" "$flags" >/proc/sys/fs/binfmt_misc/register
fi

step() { printf '\n== %s\n' "$*"; SECONDS=0; }
took() { printf '   (%d min %02d s)\n' $((SECONDS / 60)) $((SECONDS % 60)); }

if [ ! -x "$root/usr/bin/python3" ]; then
  step "debootstrap bookworm $arch into $root"
  debootstrap --arch="$arch" --include=ca-certificates,curl,sudo,git,python3,systemd \
    bookworm "$root" http://deb.debian.org/debian
  took
fi

cleanup() { for m in dev/pts dev sys proc; do umount -l "$root/$m" 2>/dev/null || true; done; }
trap cleanup EXIT
mount -t proc proc "$root/proc"
mount --rbind /sys "$root/sys"
mount --rbind /dev "$root/dev"
cp /etc/resolv.conf "$root/etc/resolv.conf"
# The host's own CAs go with its resolver (a network that inspects TLS has one): installed
# in the root's store, which pip takes; uv takes it through SSL_CERT_FILE (below).
if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
  cp /usr/local/share/ca-certificates/*.crt "$root/usr/local/share/ca-certificates/"
  chroot "$root" update-ca-certificates >/dev/null
fi

# The brewer: a login with sudo, the checkout in its home (the environment goes to /opt).
chroot "$root" sh -c 'id pi >/dev/null 2>&1 || useradd --create-home --shell /bin/bash pi'
printf '%s\n' 'pi ALL=(ALL) NOPASSWD: ALL' 'Defaults env_keep += "SSL_CERT_FILE"' \
  >"$root/etc/sudoers.d/pi"
# No one answers apt's question here: the docs' `sudo apt install ...` as written, answered yes.
echo 'APT::Get::Assume-Yes "true";' >"$root/etc/apt/apt.conf.d/90hermsd-check"
rm -rf "$root/home/pi/hermsd-checkout"
mkdir -p "$root/home/pi/hermsd-checkout"
git -C "$checkout" archive HEAD | tar -x -C "$root/home/pi/hermsd-checkout"
chroot "$root" chown -R pi:pi /home/pi/hermsd-checkout

# `doc CMD`: CMD's first line must be in the docs, then it runs as pi in the checkout.
doc() {
  local first=${1%%$'\n'*}
  grep -qF -- "${first%% \\*}" "$docs" "$checkout/README.md" \
    || { echo "not in $docs nor README.md: $first" >&2; exit 1; }
  step "$1"
  # From a file: `sudo -i` quotes a command's newlines into line continuations.
  {
    echo 'set -euo pipefail; cd ~/hermsd-checkout'
    echo 'export PATH=$HOME/.local/bin:$PATH SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt'
    printf '%s\n' "$1"
  } >"$root/tmp/hermsd-check-step.sh"
  chroot "$root" sudo -u pi -i bash /tmp/hermsd-check-step.sh
  took
}

# Astral's installer or Debian's pipx (both in the docs): pipx where astral.sh cannot be
# reached (a network of package registries only), the installer elsewhere.
if curl -fsS --max-time 10 -o /dev/null https://astral.sh/uv/install.sh; then
  doc 'curl -LsSf https://astral.sh/uv/install.sh | sh'
else
  doc 'sudo apt install pipx && pipx install uv && pipx ensurepath'
fi
if [ "$arch" = armhf ]; then
  doc 'sudo apt install build-essential python3-dev libffi-dev'
fi
doc 'for group in i2c dialout gpio; do
    getent group $group >/dev/null || sudo groupadd --system $group
done'
doc 'sudo useradd --system --no-create-home --shell /usr/sbin/nologin \
    --groups i2c,dialout,gpio hermsd'
doc 'sudo usermod -aG hermsd $USER'
doc 'uv export --frozen --no-default-groups --no-emit-project --no-hashes --extra gpio \
    -o /tmp/hermsd-constraints.txt'
doc 'sudo env UV_TOOL_DIR=/opt/hermsd UV_TOOL_BIN_DIR=/usr/local/bin \
    "$(command -v uv)" tool install --python /usr/bin/python3 \
    --constraints /tmp/hermsd-constraints.txt .'
doc 'sudo install -d -m 0755 /etc/hermsd'
doc 'sudo install -m 0640 -o root -g hermsd config/hermsd.yaml /etc/hermsd/hermsd.yaml'
doc 'hermsd check-config /etc/hermsd/hermsd.yaml'

step "checks"
chroot "$root" sh -ec '
  test "$(command -v hermsd)" = /usr/local/bin/hermsd
  install -m 0644 /home/pi/hermsd-checkout/systemd/hermsd.service /etc/systemd/system/
  systemd-analyze verify --man=no /etc/systemd/system/hermsd.service
  for example in /home/pi/hermsd-checkout/config/examples/*.yaml; do
    hermsd check-config "$example" >/dev/null
  done
  sudo -u hermsd hermsd simulate --json >/dev/null
  echo "installed: $(hermsd --help | head -n 1)"
'
took
echo "pi-install-check: $arch install as docs/raspberry-pi.md says it: OK"
