# Debian's OpenMPI carried to a machine that has none (the 16-core device machine), sourced:
#
#   here:  mkdir -p .mpi && (cd .mpi && apt-get download openmpi-bin openmpi-common libopenmpi3 \
#              libevent-core-2.1-7 libevent-pthreads-2.1-7 libfabric1 libhwloc15 libhwloc-plugins \
#              libibverbs1 ibverbs-providers libmunge2 libnl-3-200 libnl-route-3-200 libnuma1 \
#              libpmix2 libpsm-infinipath1 libpsm2-2 librdmacm1 libucx0 libpciaccess0 libxnvctrl0 \
#              libxml2 libicu72 ocl-icd-libopencl1 libx11-6 libxcb1 libxau6 libxdmcp6 libxext6 \
#              libbsd0 libmd0)
#          cargo build --release --features mpi
#   there: . scripts/carried_mpi.sh .mpi   (then $MPIRUN and target/release/mobo)
#
# The packages are unpacked under a prefix (never over /), OpenMPI is told where it now lives
# (OPAL_PREFIX), and only shared memory and self transports are used (one node).
carried=${1:-.mpi}
prefix=/tmp/ompi
mkdir -p "$prefix"
for f in "$carried"/*.deb; do dpkg -x "$f" "$prefix"; done
export OPAL_PREFIX=$prefix/usr
export PATH=$prefix/usr/bin:$PATH
export LD_LIBRARY_PATH=$prefix/usr/lib/x86_64-linux-gnu:$prefix/usr/lib/x86_64-linux-gnu/openmpi/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
export OMPI_MCA_pml=ob1 OMPI_MCA_btl=self,vader OMPI_MCA_btl_vader_single_copy_mechanism=none
export OMPI_MCA_plm_rsh_agent=false
# Debian makes `mpirun` an alternatives link at install time, which dpkg -x does not run.
ln -sf orterun "$prefix/usr/bin/mpirun"
export MPIRUN=$prefix/usr/bin/mpirun
# The host's own PMIx plugins do not match Debian's library; without compression it still runs.
export PMIX_MCA_pcompress_base_silence_warning=1
