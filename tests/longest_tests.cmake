# Read by CTest after the Catch2 tests are discovered. CTest starts the tests of highest COST first;
# a fresh clone (CI) has no recorded times and would start these in the order they were added, some
# of them last, to run alone on one core at the end. COST: about their seconds in the slower build.
# A name not defined in a build (a [release-only] test under the sanitizers) is ignored. The
# command-line tests' COST is set in CMakeLists.txt: CTest reads this file before their definitions.
set_tests_properties("simulation–estimation: Laplace and FOCEI recover a known population, FO as far as it can"
                     PROPERTIES COST 50)
set_tests_properties("second-order sensitivities on the ODE propagator agree with differences and with Φ/Γ's"
                     "third derivatives of the predictions agree with differences of the second ones"
                     "ODE routes agree: forward sensitivities, adjoint and finite differences"
                     PROPERTIES COST 18)
