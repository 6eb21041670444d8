<?xml version="1.0" encoding="UTF-8" standalone="yes"?>
<CityModel gml:id="UUID_ab2f5e3d-1c2d-4f4a-a744-a1c3a6d81c80" xmlns:con="http://www.opengis.net/citygml/construction/3.0" xmlns:tran="http://www.opengis.net/citygml/transportation/3.0" xmlns:wtr="http://www.opengis.net/citygml/waterbody/3.0" xmlns:veg="http://www.opengis.net/citygml/vegetation/3.0" xmlns="http://www.opengis.net/citygml/3.0" xmlns:dem="http://www.opengis.net/citygml/relief/3.0" xmlns:gml="http://www.opengis.net/gml/3.2" xmlns:bldg="http://www.opengis.net/citygml/building/3.0" xmlns:ct="urn:oasis:names:tc:ciq:ct:3" xmlns:grp="http://www.opengis.net/citygml/cityobjectgroup/3.0" xmlns:dyn="http://www.opengis.net/citygml/dynamizer/3.0" xmlns:pnt="http://www.opengis.net/citygml/pointcloud/3.0" xmlns:tun="http://www.opengis.net/citygml/tunnel/3.0" xmlns:frn="http://www.opengis.net/citygml/cityfurniture/3.0" xmlns:gen="http://www.opengis.net/citygml/generics/3.0" xmlns:xAL="urn:oasis:names:tc:ciq:xal:3" xmlns:app="http://www.opengis.net/citygml/appearance/3.0" xmlns:luse="http://www.opengis.net/citygml/landuse/3.0" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xmlns:brid="http://www.opengis.net/citygml/bridge/3.0" xmlns:ver="http://www.opengis.net/citygml/versioning/3.0" xmlns:xlink="http://www.w3.org/1999/xlink" xsi:schemaLocation="http://www.opengis.net/citygml/construction/3.0 http://schemas.opengis.net/citygml/construction/3.0/construction.xsd http://www.opengis.net/citygml/transportation/3.0 http://schemas.opengis.net/citygml/transportation/3.0/transportation.xsd http://www.opengis.net/citygml/waterbody/3.0 http://schemas.opengis.net/citygml/waterbody/3.0/waterBody.xsd http://www.opengis.net/citygml/vegetation/3.0 http://schemas.opengis.net/citygml/vegetation/3.0/vegetation.xsd http://www.opengis.net/citygml/relief/3.0 http://schemas.opengis.net/citygml/relief/3.0/relief.xsd http://www.opengis.net/citygml/building/3.0 http://schemas.opengis.net/citygml/building/3.0/building.xsd http://www.opengis.net/citygml/cityobjectgroup/3.0 http://schemas.opengis.net/citygml/cityobjectgroup/3.0/cityObjectGroup.xsd http://www.opengis.net/citygml/dynamizer/3.0 http://schemas.opengis.net/citygml/dynamizer/3.0/dynamizer.xsd http://www.opengis.net/citygml/pointcloud/3.0 http://schemas.opengis.net/citygml/pointcloud/3.0/pointCloud.xsd http://www.opengis.net/citygml/tunnel/3.0 http://schemas.opengis.net/citygml/tunnel/3.0/tunnel.xsd http://www.opengis.net/citygml/cityfurniture/3.0 http://schemas.opengis.net/citygml/cityfurniture/3.0/cityFurniture.xsd http://www.opengis.net/citygml/generics/3.0 http://schemas.opengis.net/citygml/generics/3.0/generics.xsd http://www.opengis.net/citygml/appearance/3.0 http://schemas.opengis.net/citygml/appearance/3.0/appearance.xsd http://www.opengis.net/citygml/landuse/3.0 http://schemas.opengis.net/citygml/landuse/3.0/landUse.xsd http://www.opengis.net/citygml/bridge/3.0 http://schemas.opengis.net/citygml/bridge/3.0/bridge.xsd http://www.opengis.net/citygml/versioning/3.0 http://schemas.opengis.net/citygml/versioning/3.0/versioning.xsd">
  <gml:name>Simple CityGML test case</gml:name>
  <gml:boundedBy>
    <gml:Envelope srsName="urn:ogc:def:crs,crs:EPSG:6.12:3068,crs:EPSG:6.12:5783" srsDimension="3">
      <gml:lowerCorner srsDimension="3">0.0 0.0 0.0</gml:lowerCorner>
      <gml:upperCorner srsDimension="3">100.0 100.0 10.0</gml:upperCorner>
    </gml:Envelope>
  </gml:boundedBy>
  <cityObjectMember>
    <bldg:Building gml:id="FZK_GUID_1F3E679D-E226-4535-926C-7390977FB25A">
      <gml:description>FZK/IAI test cases only</gml:description>
      <gml:name>Testcase-0-0_LoD2</gml:name>
      <boundary>
        <con:GroundSurface gml:id="FZK_GUID_7076142D-B7D1-48B6-901B-20CDB5968DF5">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_4ab1a80d-0c68-47af-9c03-8ad1e98ea10e">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">6.0 0.0 0.0 0.0 0.0 0.0 0.0 8.0 0.0 6.0 8.0 0.0 6.0 0.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:GroundSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_227D72FE-7D2C-4336-8D6C-24AFABF8A4DB">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_8d096cc5-3093-4f60-8430-fd1b6e838d81">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">0.0 0.0 0.0 6.0 0.0 0.0 6.0 0.0 5.0 3.0 0.0 11.0 0.0 0.0 5.0 0.0 0.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_C8C2E28B-8FAC-4E56-AFA6-C403F47F4DA3">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_8f934f24-0a64-4546-95f0-f5296c2ba2a0">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">6.0 8.0 0.0 0.0 8.0 0.0 0.0 8.0 5.0 3.0 8.0 11.0 6.0 8.0 5.0 6.0 8.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_8CC57495-6C1A-4F6F-9589-06CAAFC8EAF6">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_3987ffdc-78df-427c-baa1-9e326a2f23af">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">0.0 0.0 0.0 0.0 0.0 5.0 0.0 8.0 5.0 0.0 8.0 0.0 0.0 0.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_9959A80E-FAC6-4F18-AA8C-27B4C853164C">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_9afe46ef-dedf-4923-9805-de4ab4e4f297">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">6.0 8.0 0.0 6.0 8.0 5.0 6.0 0.0 5.0 6.0 0.0 0.0 6.0 8.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:RoofSurface gml:id="FZK_GUID_8225CA5F-2613-40E5-BA61-117AFA2628B9">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_954aee8a-2af0-497e-9494-66f45400aa5c">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">0.0 0.0 5.0 3.0 0.0 11.0 3.0 8.0 11.0 0.0 8.0 5.0 0.0 0.0 5.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:RoofSurface>
      </boundary>
      <boundary>
        <con:RoofSurface gml:id="FZK_GUID_9D7AB241-5B65-47B2-A4E3-802A63213A1F">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_b878434d-5133-4e1a-b3c4-e83ecb7e58e9">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">6.0 8.0 5.0 3.0 8.0 11.0 3.0 0.0 11.0 6.0 0.0 5.0 6.0 8.0 5.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:RoofSurface>
      </boundary>
      <lod2Solid>
        <gml:Solid>
          <gml:exterior>
            <gml:Shell>
              <gml:surfaceMember xlink:href="#UUID_4ab1a80d-0c68-47af-9c03-8ad1e98ea10e"/>
              <gml:surfaceMember xlink:href="#UUID_8d096cc5-3093-4f60-8430-fd1b6e838d81"/>
              <gml:surfaceMember xlink:href="#UUID_8f934f24-0a64-4546-95f0-f5296c2ba2a0"/>
              <gml:surfaceMember xlink:href="#UUID_3987ffdc-78df-427c-baa1-9e326a2f23af"/>
              <gml:surfaceMember xlink:href="#UUID_9afe46ef-dedf-4923-9805-de4ab4e4f297"/>
              <gml:surfaceMember xlink:href="#UUID_954aee8a-2af0-497e-9494-66f45400aa5c"/>
              <gml:surfaceMember xlink:href="#UUID_b878434d-5133-4e1a-b3c4-e83ecb7e58e9"/>
            </gml:Shell>
          </gml:exterior>
        </gml:Solid>
      </lod2Solid>
      <con:dateOfConstruction>1929-01-01</con:dateOfConstruction>
      <con:dateOfDemolition>2044-01-01</con:dateOfDemolition>
      <con:height>
        <con:Height>
          <con:highReference>highestRoofEdge</con:highReference>
          <con:lowReference>lowestGroundPoint</con:lowReference>
          <con:status>measured</con:status>
          <con:value uom="#m">11.0</con:value>
        </con:Height>
      </con:height>
      <bldg:class>1100</bldg:class>
      <bldg:roofType>1030</bldg:roofType>
      <bldg:storeysAboveGround>5</bldg:storeysAboveGround>
      <bldg:storeysBelowGround>0</bldg:storeysBelowGround>
      <bldg:storeyHeightsAboveGround uom="#m">2.0</bldg:storeyHeightsAboveGround>
      <bldg:storeyHeightsBelowGround uom="#m">0.0</bldg:storeyHeightsBelowGround>
    </bldg:Building>
  </cityObjectMember>
  <cityObjectMember>
    <bldg:Building gml:id="FZK_GUID_7C605DB2-2E94-4C2D-82CC-8B9065F7CCCA">
      <gml:description>FZK/IAI test cases only</gml:description>
      <gml:name>Testcase-0-1_LoD2</gml:name>
      <boundary>
        <con:GroundSurface gml:id="FZK_GUID_D1127B2A-B7E7-482A-9AB1-6117DDE9FFE2">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_830344c8-b837-40c9-9c12-95533436c756">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">16.0 0.0 0.0 10.0 0.0 0.0 10.0 8.0 0.0 16.0 8.0 0.0 16.0 0.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:GroundSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_85A6DD95-2BB6-4B7F-B11E-29AE6DAE4014">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_94d64c22-040f-47ea-a866-b15b71bebc2b">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">10.0 0.0 0.0 16.0 0.0 0.0 16.0 0.0 7.0 13.0 0.0 11.0 10.0 0.0 7.0 10.0 0.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_A018227E-273E-4078-BE3B-5E6E95605CF8">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_fedcbd5c-9781-4316-bcee-3d6955c1c9dc">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">16.0 8.0 0.0 10.0 8.0 0.0 10.0 8.0 7.0 13.0 8.0 11.0 16.0 8.0 7.0 16.0 8.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_FA67FF27-18CB-4609-8B42-8C78A496416B">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_35f6098f-7781-4f7a-abcb-2618a13bbbbb">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">10.0 0.0 0.0 10.0 0.0 7.0 10.0 8.0 7.0 10.0 8.0 0.0 10.0 0.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:WallSurface gml:id="FZK_GUID_AC4B6BC3-F693-406F-8463-1A05C96EBF52">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_0373cf24-4342-404a-910e-7e5055c069bd">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">16.0 8.0 0.0 16.0 8.0 7.0 16.0 0.0 7.0 16.0 0.0 0.0 16.0 8.0 0.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:WallSurface>
      </boundary>
      <boundary>
        <con:RoofSurface gml:id="FZK_GUID_C9FA006B-AE85-4A00-B73A-260DA4812839">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_fdc67fc1-7068-4970-bc06-f0cce34ee366">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">10.0 0.0 7.0 13.0 0.0 11.0 13.0 8.0 11.0 10.0 8.0 7.0 10.0 0.0 7.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:RoofSurface>
      </boundary>
      <boundary>
        <con:RoofSurface gml:id="FZK_GUID_637B2F68-6B84-480B-9CB1-50F75A496FB2">
          <lod2MultiSurface>
            <gml:MultiSurface>
              <gml:surfaceMember>
                <gml:Polygon gml:id="UUID_6eb14f41-51e1-4d66-9ce7-8d1607f8552b">
                  <gml:exterior>
                    <gml:LinearRing>
                      <gml:posList srsDimension="3">16.0 8.0 7.0 13.0 8.0 11.0 13.0 0.0 11.0 16.0 0.0 7.0 16.0 8.0 7.0</gml:posList>
                    </gml:LinearRing>
                  </gml:exterior>
                </gml:Polygon>
              </gml:surfaceMember>
            </gml:MultiSurface>
          </lod2MultiSurface>
        </con:RoofSurface>
      </boundary>
      <lod2Solid>
        <gml:Solid>
          <gml:exterior>
            <gml:Shell>
              <gml:surfaceMember xlink:href="#UUID_830344c8-b837-40c9-9c12-95533436c756"/>
              <gml:surfaceMember xlink:href="#UUID_94d64c22-040f-47ea-a866-b15b71bebc2b"/>
              <gml:surfaceMember xlink:href="#UUID_fedcbd5c-9781-4316-bcee-3d6955c1c9dc"/>
              <gml:surfaceMember xlink:href="#UUID_35f6098f-7781-4f7a-abcb-2618a13bbbbb"/>
              <gml:surfaceMember xlink:href="#UUID_0373cf24-4342-404a-910e-7e5055c069bd"/>
              <gml:surfaceMember xlink:href="#UUID_fdc67fc1-7068-4970-bc06-f0cce34ee366"/>
              <gml:surfaceMember xlink:href="#UUID_6eb14f41-51e1-4d66-9ce7-8d1607f8552b"/>
            </gml:Shell>
          </gml:exterior>
        </gml:Solid>
      </lod2Solid>
      <con:dateOfConstruction>1905-01-01</con:dateOfConstruction>
      <con:dateOfDemolition>2053-01-01</con:dateOfDemolition>
      <con:height>
        <con:Height>
          <con:highReference>highestRoofEdge</con:highReference>
          <con:lowReference>lowestGroundPoint</con:lowReference>
          <con:status>measured</con:status>
          <con:value uom="#m">11.0</con:value>
        </con:Height>
      </con:height>
      <bldg:class>1130</bldg:class>
      <bldg:roofType>1030</bldg:roofType>
      <bldg:storeysAboveGround>3</bldg:storeysAboveGround>
      <bldg:storeysBelowGround>0</bldg:storeysBelowGround>
      <bldg:storeyHeightsAboveGround uom="#m">3.0</bldg:storeyHeightsAboveGround>
      <bldg:storeyHeightsBelowGround uom="#m">0.0</bldg:storeyHeightsBelowGround>
    </bldg:Building>
  </cityObjectMember>
</CityModel>