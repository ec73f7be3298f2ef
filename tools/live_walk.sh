#!/usr/bin/env bash
# The main POS graph on the walk_0827 recording, live, and its comparison with the offline run.
#
#   tools/live_walk.sh RATE [DOMAIN_ID]      (from the repository root; RATE 1, 5, 0 = as fast as possible)
#
# Imports the recording into out/walk_0827_1hz when missing (GNSS 1 Hz, outage [60, 75) s), starts
# data/real/walk_0827/graph.yaml (ifa_node + pos_master_node, device: ros), records /master/nav and
# the statuses, plays the bag at RATE, stops the graph and writes the report
# out/live/walk_<RATE>x_report (dpos-ifa --live: live - offline, rejected fixes, lost corrections).
set -euo pipefail
rate=${1:?usage: tools/live_walk.sh RATE [DOMAIN_ID]}
domain=${2:-$((60 + RANDOM % 100))}
bin=.venv/bin
w=data/real/walk_0827
bag=out/walk_0827_1hz
name=out/live/walk_${rate}x
mkdir -p out/live
if [ ! -f "$bag/metadata.yaml" ]; then
  "$bin/dpos-import" --imu $w/imu_1730.csv --tag $w/imu_1730.csv.tag --pos $w/gnss_1730_sf.pos \
    --gnss-rate 1 --outage 60:75 --out "$bag"
fi
rm -rf "$name" "${name}_report"
export ROS_DOMAIN_ID=$domain
"$bin/dpos-graph" $w/graph.yaml --domain-id "$domain" > "$name.graph.log" 2>&1 &
graph=$!
for _ in $(seq 600); do  # the graph's subscriptions exist before the replay starts (graph.yaml "ready")
  grep -q "node(s) ready" "$name.graph.log" && break
  kill -0 $graph 2>/dev/null || { echo "dpos-graph exited:"; tail -5 "$name.graph.log"; exit 1; }
  sleep 0.2
done
sleep 1  # discovery of the matched endpoints settles
"$bin/dpos-record" --out "$name" --duration 900 /master/nav /dpos/datum /ifa/status /pos_master/status \
  > "$name.rec.log" 2>&1 &
rec=$!
for _ in $(seq 300); do  # the recorder has matched /master/nav before the replay starts
  grep -q "recording /master/nav (" "$name.rec.log" && break
  sleep 0.2
done
start=$(date +%s.%N)
rc=0; "$bin/dpos-play" "$bag" --rate "$rate" --min-subscribers 1 --wait-subscribers 120 > "$name.play.log" 2>&1 || rc=$?
echo "play exit $rc after $(echo "$(date +%s.%N) - $start" | bc) s"
sleep "${SETTLE_S:-15}"  # what the graph still has in flight
kill -INT $rec; rc=0; wait $rec || rc=$?; echo "rec exit $rc"
kill -INT $graph; rc=0; wait $graph || rc=$?; echo "graph exit $rc"
"$bin/dpos-ifa" "$bag" --params-file $w/ifa_node.yaml --min-course-speed 0 --reference $w/gnss_1730_sf.pos \
  --outage 60:75 --live "$name" --out "${name}_report"
tail -12 "${name}_report/report.md"
