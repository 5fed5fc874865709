"""What a run leaves, read without ROS: its trajectory accumulated from ``/swarm/state``
(:mod:`.samples`), its files and ``summary.json`` (:mod:`.runio`), the studies of the
paper's claims (:mod:`.studies`) and the figures (:mod:`.plots`). The bring-up, the bag tools
and the command line use it; it uses none of them."""
