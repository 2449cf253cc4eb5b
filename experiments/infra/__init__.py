"""The infrastructure every bench shares: the resumable sweep runner (:mod:`.sweep`), probe
jobs of known cost (:mod:`.probe`), the runner's overhead per job (:mod:`.overhead`) and the
package's robustness figures (:mod:`.robustness`)."""
