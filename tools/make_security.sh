#!/usr/bin/env bash
# Test credentials for DDS Security (docs/SECURITY.md; configs/cyclonedds/secure.xml): a test
# CA, a key and CA-signed certificate per identity, and the governance and permissions
# documents signed by that CA (S/MIME, as Cyclone's access-control plugin reads them).
#
#   tools/make_security.sh [--out DIR] [--identities "physd client1 client2"]
#                          [--servers "physd"] [--days N]
#
# DIR (default: <source>/build/security) then holds
#   ca_key.pem ca_cert.pem                    the test CA (EC prime256v1, self-signed)
#   <name>_key.pem <name>_cert.pem            per identity, subject CN=<name>,O=physd-test
#   governance.xml governance.p7s             domains 0-230, everything protected
#   permissions.xml permissions.p7s           a grant per identity, domains 0-230: a server
#                                             (--servers) publishes and subscribes anywhere;
#                                             a client subscribes anywhere and publishes only
#                                             in partition phys.id.<name>, which is how physd
#                                             tells who sent a command (docs/SECURITY.md)
#
# Domains stop at 230, not DDS's 232: Cyclone 0.10's access-control plugin rejects a governance
# or permissions document with a domain id above 230 ("Can not parse governance file").
#
# Idempotent: a CA, key or certificate already there is kept while it is valid (a certificate
# also while it verifies against the CA); the documents are remade only when their contents
# change (other identities, a new CA, permissions that expire within a day). Nothing but
# openssl is needed. The CA's key lies unencrypted next to the rest: test credentials only.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="$root/build/security" identities="physd client1 client2" servers="physd" days=365
usage() { echo "usage: $0 [--out DIR] [--identities \"NAME ...\"] [--servers \"NAME ...\"] [--days N]" >&2; exit 2; }
while [[ $# -gt 0 ]]; do
  case "$1" in
    --out) [[ $# -ge 2 ]] || usage; out="$2"; shift 2 ;;
    --identities) [[ $# -ge 2 ]] || usage; identities="$2"; shift 2 ;;
    --servers) [[ $# -ge 2 ]] || usage; servers="$2"; shift 2 ;;
    --days) [[ $# -ge 2 ]] || usage; days="$2"; shift 2 ;;
    -h|--help) usage ;;
    *) usage ;;
  esac
done
[[ "$days" =~ ^[1-9][0-9]*$ ]] || { echo "$0: --days wants a positive number" >&2; exit 2; }
command -v openssl > /dev/null || { echo "$0: openssl not found" >&2; exit 1; }
read -r -a names <<< "$identities"
[[ ${#names[@]} -gt 0 ]] || { echo "$0: no identities" >&2; exit 2; }
for n in "${names[@]}"; do
  # Names go into file names, certificate subjects and XML: keep them plain.
  [[ "$n" =~ ^[A-Za-z0-9][A-Za-z0-9_.-]*$ ]] || { echo "$0: bad identity name '$n'" >&2; exit 2; }
done

mkdir -p "$out"
out="$(cd "$out" && pwd)"
umask 077  # keys: owner only
org="physd-test"
ca_key="$out/ca_key.pem" ca_cert="$out/ca_cert.pem"
say() { printf '%-8s %s\n' "$1" "$2"; }

# A certificate is usable when it parses, stays valid for another day and matches its key.
cert_ok() {  # cert key
  [[ -s "$1" && -s "$2" ]] || return 1
  openssl x509 -in "$1" -noout -checkend 86400 > /dev/null 2>&1 || return 1
  [[ "$(openssl x509 -in "$1" -noout -pubkey 2> /dev/null)" == \
     "$(openssl pkey -in "$2" -pubout 2> /dev/null)" ]]
}

# The CA.
if cert_ok "$ca_cert" "$ca_key"; then
  say kept "$ca_cert"
else
  openssl ecparam -name prime256v1 -genkey -noout -out "$ca_key"
  openssl req -new -x509 -sha256 -key "$ca_key" -out "$ca_cert" -days "$days" \
    -subj "/O=$org/CN=physd-test-ca" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,digitalSignature,keyCertSign,cRLSign"
  say made "$ca_cert (test CA, EC prime256v1, $days days)"
  ca_new=1
fi

# The identities.
for n in "${names[@]}"; do
  key="$out/${n}_key.pem" cert="$out/${n}_cert.pem"
  if [[ -z "${ca_new:-}" ]] && cert_ok "$cert" "$key" &&
     openssl verify -CAfile "$ca_cert" "$cert" > /dev/null 2>&1; then
    say kept "$cert"
    continue
  fi
  if ! openssl pkey -in "$key" -noout 2> /dev/null; then
    openssl ecparam -name prime256v1 -genkey -noout -out "$key"
  fi
  csr="$(mktemp)" ext="$(mktemp)"
  printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature,keyAgreement\n' > "$ext"
  openssl req -new -sha256 -key "$key" -subj "/O=$org/CN=$n" -out "$csr"
  openssl x509 -req -sha256 -in "$csr" -CA "$ca_cert" -CAkey "$ca_key" -CAcreateserial \
    -CAserial "$out/ca_cert.srl" -days "$days" -extfile "$ext" -out "$cert" 2> /dev/null
  rm -f "$csr" "$ext"
  say made "$cert (CN=$n,O=$org)"
done

# Signs $1.xml into $1.p7s with the CA unless the signed copy is current; $2: the new text.
sign_doc() {  # base text
  local xml="$out/$1.xml" p7s="$out/$1.p7s"
  if [[ -z "${ca_new:-}" && -s "$xml" && -s "$p7s" && "$(cat "$xml")" == "$2" ]] &&
     openssl smime -verify -in "$p7s" -CAfile "$ca_cert" -out /dev/null > /dev/null 2>&1; then
    say kept "$p7s"
    return
  fi
  printf '%s\n' "$2" > "$xml"
  openssl smime -sign -text -in "$xml" -signer "$ca_cert" -inkey "$ca_key" -out "$p7s"
  say made "$p7s"
}

domains='<domains>
        <id_range>
          <min>0</min>
          <max>230</max>
        </id_range>
      </domains>'

# Governance: only authenticated participants join; discovery, liveliness and every RTPS
# message are encrypted; every topic needs read and write permission, and its data and
# metadata are encrypted.
sign_doc governance "<?xml version=\"1.0\" encoding=\"utf-8\"?>
<dds xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\"
    xsi:noNamespaceSchemaLocation=\"https://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd\">
  <domain_access_rules>
    <domain_rule>
      $domains
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>ENCRYPT</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>"

# Permissions: one grant per identity, valid from now for --days; kept (with its validity)
# while it names the same identities and stays valid for another day.
perm_xml="$out/permissions.xml"
not_after_old="" subjects_old="" subjects=""
for n in "${names[@]}"; do subjects+="CN=$n,O=$org;"; done
if [[ -s "$perm_xml" ]]; then
  not_after_old="$(sed -n 's:.*<not_after>\(.*\)</not_after>.*:\1:p' "$perm_xml" | head -1)"
  subjects_old="$(sed -n 's:.*<subject_name>\(.*\)</subject_name>.*:\1;:p' "$perm_xml" | tr -d '\n')"
fi
if [[ -z "${ca_new:-}" && -n "$not_after_old" && "$subjects_old" == "$subjects" ]] &&
   [[ "$(date -u -d "$not_after_old" +%s 2> /dev/null || echo 0)" -gt "$(( $(date -u +%s) + 86400 ))" ]]; then
  not_before="$(sed -n 's:.*<not_before>\(.*\)</not_before>.*:\1:p' "$perm_xml" | head -1)"
  not_after="$not_after_old"
else
  not_before="$(date -u +%Y-%m-%dT%H:%M:%S)"
  not_after="$(date -u -d "+$days days" +%Y-%m-%dT%H:%M:%S)"
fi
grants=""
for n in "${names[@]}"; do
  # A client's writers (its commands) only in its own identity partition: a command that
  # physd reads there was written with this identity's certificate.
  publish_partition="phys.id.$n"
  [[ " $servers " == *" $n "* ]] && publish_partition="*"
  grants+="
    <grant name=\"${n}_permissions\">
      <subject_name>CN=$n,O=$org</subject_name>
      <validity>
        <not_before>$not_before</not_before>
        <not_after>$not_after</not_after>
      </validity>
      <allow_rule>
        $domains
        <publish>
          <topics><topic>*</topic></topics>
          <partitions><partition>$publish_partition</partition></partitions>
        </publish>
        <subscribe>
          <topics><topic>*</topic></topics>
          <partitions><partition>*</partition></partitions>
        </subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>"
done
sign_doc permissions "<?xml version=\"1.0\" encoding=\"utf-8\"?>
<dds xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\"
    xsi:noNamespaceSchemaLocation=\"https://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd\">
  <permissions>$grants
  </permissions>
</dds>"

chmod 644 "$out"/*.pem "$out"/*.xml "$out"/*.p7s
chmod 600 "$out"/*_key.pem
echo "security files in $out (identities: ${names[*]}); use with"
echo "  PHYS_SECURITY_DIR=$out PHYS_IDENTITY=<name> and configs/cyclonedds/secure.xml"
