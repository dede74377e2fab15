#!/bin/bash
G=/root/runs/gate3/oneh.sh
for set in "2 0" "2 0.05" "full 0" "full 0.05"; do $G hint0 amat:/root/runs/gate3/hint0.pt $set; done
echo done $(date)
