# physbench --sweep, scene pyramid_40: run from this directory: gnuplot pyramid_40.gp
# ms per step against the error, log scales; lines join each config's front, whose
# points carry their budget (substeps x iterations, or a peer's iterations).
set logscale xy
set grid
set format x '%g'
set format y '%g'
set xlabel 'ms per step (median)'
set ylabel "top_drift (m)"
set title "pyramid_40"
set key outside right top title 'line: front'
if (strstrt(GPVAL_TERMINALS, 'pngcairo') > 0) {
  set terminal pngcairo size 1000,650 noenhanced font ',10'
} else {
  set terminal png size 1000,650 noenhanced
}
set output "pyramid_40.png"
plot "pyramid_40.dat" index 0 using 1:2 with points lc rgb "#1f77b4" pt 7 ps 1.3 notitle, \
     '' index 1 using 1:2 with linespoints lc rgb "#1f77b4" dt 1 lw 1.5 pt 7 ps 1.3 title "soft_step", \
     '' index 1 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#1f77b4" notitle, \
     "pyramid_40.dat" index 2 using 1:2 with points lc rgb "#2ca02c" pt 5 ps 1.3 notitle, \
     '' index 3 using 1:2 with linespoints lc rgb "#2ca02c" dt 1 lw 1.5 pt 5 ps 1.3 title "pgs", \
     '' index 3 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#2ca02c" notitle, \
     "pyramid_40.dat" index 4 using 1:2 with points lc rgb "#9467bd" pt 9 ps 1.3 notitle, \
     '' index 5 using 1:2 with linespoints lc rgb "#9467bd" dt 1 lw 1.5 pt 9 ps 1.3 title "tjsoft", \
     '' index 5 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#9467bd" notitle, \
     "pyramid_40.dat" index 6 using 1:2 with points lc rgb "#d62728" pt 6 ps 1.3 notitle, \
     '' index 7 using 1:2 with linespoints lc rgb "#d62728" dt 2 lw 1.5 pt 6 ps 1.3 title "bullet", \
     '' index 7 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#d62728" notitle, \
     "pyramid_40.dat" index 8 using 1:2 with points lc rgb "#ff7f0e" pt 4 ps 1.3 notitle, \
     '' index 9 using 1:2 with linespoints lc rgb "#ff7f0e" dt 2 lw 1.5 pt 4 ps 1.3 title "ode", \
     '' index 9 using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "#ff7f0e" notitle
set terminal svg size 1000,650 noenhanced font 'sans,12'
set output "pyramid_40.svg"
replot
unset output
