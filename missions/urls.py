from django.urls import path

from missions import views

urlpatterns = [
    path("", views.home, name="home"),
    path("vvs/<uuid:vv_id>/", views.vv_detail, name="vv-detail"),
    path("vvs/<uuid:vv_id>/map.json", views.vv_map_history, name="vv-map-history"),
    path("map/", views.live_map, name="map"),
]
